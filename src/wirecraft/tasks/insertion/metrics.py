"""What the evaluation measures for connector insertion: depth and alignment at the port,
insertion force, reach and insert success, the misalignment and jam failure labels, and the
retention pull on the plug."""

from __future__ import annotations

import math

import numpy as np

from wirecraft.assets.connectors import CONNECTORS
from wirecraft.numerics import norm
from wirecraft.tasks.insertion.task import LATERAL_TOLERANCE, ROLL_GATE, InsertionTask
from wirecraft.tasks.metrics import TaskMetrics, final, metrics_of

ORIENTATION_TOLERANCE = ROLL_GATE  # rad (10 deg), for roll and axis tilt alike
JAM_FORCE = 2.0  # N, plug against the port
JAM_STEPS = 30  # control steps (0.5 s)
JAM_PROGRESS = 0.0005  # m of depth over those steps


def stalled_under_force(depth: np.ndarray, force: np.ndarray, window: np.ndarray) -> bool:
    """``JAM_STEPS`` consecutive steps inside ``window`` with the force >= ``JAM_FORCE`` and
    the depth moving less than ``JAM_PROGRESS``."""
    pressed = window & (np.nan_to_num(force) >= JAM_FORCE)
    start = None
    for k, flag in enumerate([*pressed, False]):
        if flag and start is None:
            start = k
        elif not flag and start is not None:
            for a in range(start, k - JAM_STEPS + 1):
                segment = depth[a : a + JAM_STEPS]
                if np.nanmax(segment) - np.nanmin(segment) < JAM_PROGRESS:
                    return True
            start = None
    return False


@metrics_of(InsertionTask)
class InsertionMetrics(TaskMetrics):
    success_flags = ("success", "reach_success", "insert_success")
    columns = (
        "insertion_depth",  # m past the socket mouth
        "lateral_error",  # m off the socket axis
        "yaw_error",  # rad, plug axis vs socket axis
        "roll_error",  # rad about the axis, modulo symmetry
        "insertion_force",  # N, plug against the port
        "tip_distance",  # m, plug tip to the socket entry
        "reach",  # 0/1: info["reach_success"]
    )
    info_keys = {"reach": "reach_success"}
    failure_labels = {
        "yaw_misaligned": (
            "at the port (deepest point), the plug's roll about the socket axis or the tilt of "
            f"its axis was off by more than {math.degrees(ORIENTATION_TOLERANCE):.0f} deg"
        ),
        "lateral_misaligned": (
            "at the port (deepest point), the tip was off the socket axis by more than the "
            f"clearance + {1000 * LATERAL_TOLERANCE:g} mm"
        ),
        "jammed": (
            f"at the port and aligned, but stalled: insertion force >= {JAM_FORCE:g} N for "
            f"{JAM_STEPS} steps while the depth moved less than {1000 * JAM_PROGRESS:g} mm"
        ),
    }
    trace_plots = (
        ("insertion_depth", "insertion depth (mm)", 1000.0, (-40.0, 25.0)),
        ("insertion_force", "insertion force (N)", 1.0, None),
        ("lateral_error", "lateral error (mm)", 1000.0, (0.0, 30.0)),
        ("wire_tension", "wire tension (N)", 1.0, None),
    )
    episode_columns = ("reach_success", "max_insertion_depth", "max_insertion_force")
    pulls = True

    def measure(self, env, info: dict) -> dict[str, float]:
        row = self.from_info(info)
        task, data = env.task, env.data
        tip = data.site_xpos[task.assembly.tip_site]
        row["tip_distance"] = norm(tip - data.site_xpos[task.entry_site])
        return row

    def at_goal(self, trace, held):
        """The plug within reach of the socket."""
        del held
        return np.nan_to_num(trace["reach"]) > 0.5

    def at_goal_labels(self, trace, at_goal, options) -> list[str]:
        depth = trace["insertion_depth"]
        # The decisive moment: the deepest the plug got while at the port.
        k = int(np.nanargmax(np.where(at_goal, depth, -np.inf)))
        labels = []
        if max(trace["roll_error"][k], trace["yaw_error"][k]) > ORIENTATION_TOLERANCE:
            labels.append("yaw_misaligned")
        if trace["lateral_error"][k] > options.clearance + LATERAL_TOLERANCE:
            labels.append("lateral_misaligned")
        if stalled_under_force(depth, trace["insertion_force"], at_goal):
            labels.append("jammed")
        return labels

    def summarize(self, episode, steps):
        return {
            "reach_success": bool((episode["reach"] > 0.5).any()),
            "insert_success": bool((episode["success"] > 0.5).any()),
            "max_insertion_depth": np.nanmax(episode["insertion_depth"], initial=-np.inf),
            "final_insertion_depth": final(episode["insertion_depth"], steps),
            "final_lateral_error": final(episode["lateral_error"], steps),
            "final_yaw_error": final(episode["yaw_error"], steps),
            "final_roll_error": final(episode["roll_error"], steps),
            "max_insertion_force": np.nanmax(episode["insertion_force"], initial=0.0),
        }

    def standard_variants(self):
        return [{"connector": name, "clearance": 0.003} for name in CONNECTORS.names()]

    def retention_pull(self, task, data):
        """The plug, out of the socket (against the socket axis)."""
        return task.assembly.plug_id, -data.xmat[task.port_id].reshape(3, 3)[:, 0]
