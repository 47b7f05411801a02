"""Teleoperation with recording: a person drives the robot in MuJoCo's viewer (keyboard,
SpaceMouse or game pad) and saves episodes into the shared LeRobot dataset schema with
``source = "teleop"``; a recorded command stream replays without a person or a display.

``devices`` (commands per control step), ``session`` (``TeleopSession``: the loop, the
dataset), ``viewer`` (the display and its overlay), ``command`` (the command line:
``python -m wirecraft.teleop``).  The devices' packages are imported only when used.
"""

from wirecraft.teleop.devices import DEVICES, EVENTS, KEY_MAP, Command, Device, make_device
from wirecraft.teleop.session import TeleopReport, TeleopSession

__all__ = [
    "DEVICES",
    "EVENTS",
    "KEY_MAP",
    "Command",
    "Device",
    "TeleopReport",
    "TeleopSession",
    "make_device",
]
