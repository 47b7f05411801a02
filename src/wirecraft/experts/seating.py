"""Scripted expert for channel seating (``WireCraft/ChannelSeating-v0``, ``cartesian`` control).

What it reads (privileged; per environment ``env = env_or_envs.unwrapped``, never the task's
success flags or ``fraction_inside``):

- ``env.model`` / ``env.data``: the MuJoCo state of that environment;
- ``env.task.assembly``: ``plug_pose(data)`` (plug origin at the back of the tail; the wire
  ends ``wire.end_gap`` behind it) and the ``grasp_site`` (middle of the tail);
  ``wire.config.radius``;
- ``env.task``: ``placed`` (the channel of this episode: ``pos``, ``yaw`` and ``config`` with
  its ``centerline``, ``floor`` and ``wall_height``), ``plug_lead`` (wire between the
  channel's end and the wire's end when seated), ``tcp_site`` and
  ``pad_contacts(model, data, held_contacts)`` (both pads on the plug), ``pads`` and
  ``assembly.wire_contacts`` (the contact normals between them, once, at the release's end);
- ``env.robot``: ``tcp_pose_base(model, data)``, ``gripper_opening``, ``gripper_velocity``,
  ``max_opening``, ``pad_geom_names`` (the pressing pad's box: ``model.geom_size``,
  ``data.geom_xpos/xmat``);
- ``env.wire_points()``: the wire's centre line (only to decide whether to press);
- ``env.controller``: its own target and base frame, through ``wirecraft.control.servo_action``.

Control mode: ``cartesian`` (7-d actions), although the task's default is ``cartesian_fixed``
(SPEC: each scripted policy selects the control mode best suited to its task).  Every phase
up to the pressing pass holds the episode's start orientation (pointing down, pads closing
along the base y axis, across the channel's first segment), exactly as ``cartesian_fixed``
would; only the pressing pass turns the TCP about the vertical so the pressing pad follows
the channel (why: below).  Every goal is a TCP pose in the robot base frame, and every phase
moves the controller's target at most a few millimetres per step (``SeatingExpertConfig``
speeds: finer than the controller's 1 cm per step).

Phases (``PHASES``): approach (above the tail) -> descend -> settle (pads open and still for a
randomized delay: the gentle, delayed grasp) -> close -> lift (straight up) -> carry (the plug
to above the channel's path, ``lay_from`` metres of arc before its end, or until the TCP stops)
-> lay (the plug follows the channel's centre line to ``plug_lead`` beyond its end while coming
down, slowly, so the wire behind it drops between the walls) -> place (the wire end down to the
height of a wire resting on the channel floor, or until the TCP stops: the plug rests on the
board) -> release (pads ``release_open`` apart) -> retreat (first ``retreat_slide`` sideways,
the way the wire pushes the pads it touches, then up: a springy wire pressed against a pad rode
up with it by friction and was dragged along the channel) -> the tuck (below), when the wire
has sprung out over the walls, then the pressing pass; or, when a wire point still rides
``press_needed`` above resting on the floor (the expert's own geometric check), the pressing
pass at once: press_approach -> press_descend -> press -> press_retreat (straight up to the
travel height), repeated (one pass per entry of ``press_directions``) while the check still
sees a raised wire, -> done. The first pass covers the whole channel, a later one only the
raised stretch (``press_lead_in`` / ``press_lead_out``): the 480-step episode rarely had room
for a second whole pass. A grasp that does not hold after the lift sends the environment back
to ``approach`` (at most ``max_grasp_retries`` times).

Pressing pass (why: held only at the bolted clamp and the plug, the stiff wire keeps one smooth
shape that bridges the curved channel's bends on the wall tops; pressed onto the floor, a
stretch stays there, held by the walls).  With the pads open, one pad (its 22 x 6 mm bottom
face) slides along the channel's centre line from ``press_from`` past the entry to
``press_stop`` before the end, its long side turned onto the channel's heading: the TCP yaw
(about the vertical, from the start orientation) follows the heading through a dead band of
``press_yaw_slack`` (smaller bends need no turn) averaged over ``press_turn_window`` of arc
(gradual turns through the bends), and the pad slows down where that profile turns faster than
``press_turn_rate`` per step.  Where the turned footprint fits between the walls it goes down
to the top of a seated wire (``press_squeeze``; no lower: a pad below it wedged a capsule
against the floor, and the wire shot out; the soft FEM wire, which the pad squashes, is
pushed 0.5 mm below it: ``WIRE_SETTINGS``) and pushes the wire onto the floor; elsewhere (and
``press_window`` of arc around) it passes ``press_clearance`` above the wall tops.  The
profile (heights and yaws) is computed once per episode from the channel geometry and the
pad's box in the model (``_press_profile``).  Held at the start orientation (the
``cartesian_fixed`` design) the pad fits only where the channel runs within ~16 deg of base x
(22 sin(a) + 6 cos(a) <= 12 mm): curved tuning seeds 0-49, 40/50 with two such passes; turned,
it fits along ~85% of the channel and one pass usually suffices (46/50; held-out seeds
1000-1099: 82%, against 75% fixed).  While the pad lags more than ``press_lag`` behind its
goal the goal slows down (``press_lag_slowdown``): chasing a goal far ahead, the pad would
cut the bends into the walls (with no slow-down at all a WidowX AI pad caught on a wall corner
2-4 cm behind its goal, broke free and the wire diverged); the slowed goal also rises
``press_lag_lift``: a pad that lags has usually stalled on the wire, pressing it hard enough to
drag it along by friction, and a lighter touch lets it slide on.  Between the
release and the pass the pads travel ``press_hover`` above the wall tops, and the release opens
them wide, so that neither the plug nor the wire near it rides along.  Passes from the end back
towards the entry were tried (fixed orientation) and are worse: pressing from the end pins the
wire's free end first, so the slack the pad pushes along has nowhere to go.

Tuck (why: released, the stiff wire springs towards the straight line from the clamp to the
plug; where the channel bends away from that line, the wire's middle stretch lies up to 4 cm
beside the channel, over the board, and a pad following the channel's centre line never
touched it).  When an inner wire point between ``press_from`` and the pass's end lies more
than ``tuck_outside`` outside the inner walls, its centre above ``press_clearance`` over the
wall tops (lower, it leans on the wall's outside, out of reach of a pad above the walls), a
pad comes down beside the farthest such point on its far side from the channel
(``tuck_margin`` beyond the wire), pushes it at ``tuck_speed`` across to the channel's centre
line (or until the pad stops) and rises: tuck_approach -> tuck_descend -> tuck_push ->
tuck_retreat -> the pressing pass.  The pushing pad is the one on the channel's side of the
TCP, so the other comes down farther out and the wire never lies between the open pads.  No
tuck while the plug, flung up as the wire sprang, hangs between the open fingers (above the
pads' bottoms): moving the pads then dragged it along and folded the wire into a hairpin.
The TCP keeps its orientation (turning at the controller's 0.01 rad per step cost ~30 steps
more) and does not press the wire down there (~30 steps more; the pass does it): ~40 steps
in all.  A first version that did both cost ~150 steps and ran seeds that had succeeded out
of time.  The rod gets no tuck (it did no better with it), and the FEM wire's tuck waits for
a wire farther out: nearer, the pass draws the FEM wire in by itself, and a tuck there did
harm (``WIRE_SETTINGS``, the per-wire settings).  Measured in docs/experts.md ("The tuck", "The FEM
wire's tuck").

Pads off the walls and the table (why: the gripper's fingers close with a limited force, and
a pad pushed down onto something pries them open).  During the lay and the place the goal is
raised so that both pads' bottoms stay ``lay_table_clearance`` above the table and, where a
pad passes over the channel (walls included), ``lay_wall_clearance`` above the wall tops.
Without it, a pad came down on the wall near the channel's end and the plug dropped from 2-3
cm, its wire bowed up and later sprang it into the air; or the pads, pushed onto the table
with the plug already on the board, were pried open while the place ran to its timeout.
Measured in docs/experts.md ("Pads off the walls and the table").

``lay_turn`` (off; tried) also turns the held plug onto the channel's last segment during
carry, lay and place: worse (5 failures in the first 26 tuning seeds against 3 in 50), and the
turns there and back cost up to ~140 steps.

Diversity (from ``config.seed``): the settle delay before closing and the lay's speed (a
per-episode slow-down factor) are drawn per episode.
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from wirecraft import validation
from wirecraft.assets.wires import WIRE_MODELS
from wirecraft.experts.base import EXPERTS, TABLE_Z, UP, ScriptedExpert, flat, horizontal
from wirecraft.experts.fsm import Phase, unwrap_envs
from wirecraft.geometry import arc_lengths, axis_angle_to_mats
from wirecraft.numerics import arctan2, cross, dot, matmul, norm
from wirecraft.sensors import contact_push

# The seating expert's per-wire settings, in one place: wire model -> {config field: value}
# replacing the default for that wire (``SeatingExpertConfig.wire_settings``).  Why each:
# - rod, fem ``press_lag``: a wire that bends anywhere is dragged along and out of the channel
#   by a pad 1-2 cm behind its goal rather than pressed in (rod, curved, held out: 94 % at some
#   step with 2 cm, 96 % with 8 mm; one validation episode diverged as the pad fell 24 mm
#   behind); the articulated wire's rigid links keep 2 cm.
# - fem ``press_squeeze``: the soft FEM wire is squashed by the pad rather than wedged (the
#   wedge was traced on capsules only), so it keeps 0.5 mm: at 0 the pass left it raised on
#   held-out straight seed 1019, and a second pass pulled it out (thin evidence).
# - fem ``tuck_outside``: the pressing pass draws in a FEM wire whose farthest point lay
#   16-28 mm from the centre line, and a tuck there lost 7 of 100 validation episodes; it never
#   drew in one 43-51 mm out.  Curved, UR5, at the end: validation 99 %, held out 98 %.
# - rod ``tuck``: built for the articulated wire's rigid links (held out: 92 -> 96 %), the tuck
#   does not help the rod (94 / 91 % with it against 96 / 93 % without, held out).
WIRE_SETTINGS: dict[str, dict[str, object]] = {
    "rod": {"press_lag": 0.008, "tuck": False},
    "fem": {"press_lag": 0.008, "press_squeeze": 0.0005, "tuck_outside": 0.035},
}


@dataclass(frozen=True)
class SeatingExpertConfig:
    """Geometry and speeds of the seating expert (SI units; per control step where stated)."""

    hover: float = 0.05  # m above the grasp point where the approach ends
    grasp_height: float = 0.010  # m: TCP above the table when grasping (pads 2 mm clear)
    pre_open: float = 0.04  # m: pad gap while approaching and settling
    # m: pad gap when releasing the plug (capped at the robot's): wide enough that a plug held
    # at a slant across the pads drops out instead of riding up with them
    release_open: float = 0.08
    settle_steps: int = 6  # control steps with the pads open and still before closing
    settle_jitter: int = 12  # + uniform 0..jitter extra steps (delayed-grasp diversity)
    lift: float = 0.06  # m: TCP height above the table after the lift
    lay_from: float = 0.04  # m of path arc before its end where the lay starts
    lay_height: float = 0.04  # m: wire end above the floor at the start of the lay
    place_above: float = 0.0005  # m: wire end above resting on the channel floor
    approach_speed: float = 0.01  # m per step (the controller's own limit)
    descend_speed: float = 0.004  # m per step
    lift_speed: float = 0.004  # m per step
    carry_speed: float = 0.006  # m per step
    lay_turn: bool = False  # turn the held plug onto the channel's last segment (carry .. place)
    # The pads close across the plug's tail when its axis lies within this angle of the line
    # they hold things along (the start orientation's); a plug lying farther round, they came
    # down on its top (rod wire, 47-53 deg).  Beyond it the TCP turns by the excess about the
    # vertical for the grasp and the lift, and back to the start orientation while carrying.
    grasp_yaw_free: float = math.radians(35.0)
    # While the pads (the lowest part of the hand) pass over the channel during the lay and
    # the place, their bottoms stay this far above the wall tops (None: no such guard).  A pad
    # that came down on a wall near the channel's end was pried open by the arm pushing down,
    # and the plug dropped from 2-3 cm (its wire bowed up and later sprang it into the air).
    lay_wall_clearance: float | None = 0.002  # m
    # m: a pad face this close (horizontally) to the channel's walls counts as over them.  Not
    # more: a plug held centred and lined up with the channel keeps the pads' inner faces
    # 1.2-1.5 mm outside its outer walls (UR5), and they come down beside them.
    lay_wall_reach: float = 0.0005
    # m: the pads' bottoms stay this far above the table during the lay and the place (None:
    # no such floor).  Pushed onto the table with the plug already on the board, the pads were
    # pried open too, and the place ran to its timeout (the TCP slid sideways as they opened).
    lay_table_clearance: float | None = 0.001
    lay_speed: float = 0.002  # m per step along the path (before the slow-down)
    lay_slowdown: tuple[float, float] = (1.0, 1.6)  # per-episode lay time factor (diversity)
    place_speed: float = 0.001  # m per step
    # The place ends once the TCP has moved less than place_stall_distance for
    # place_stall_steps: a plug that rests on the board cannot go lower, and waiting out the
    # timeout cost ~45 of the 480 steps, which the pressing pass then lacked.
    place_stall_distance: float = 0.001  # m
    place_stall_steps: int = 8
    retreat: float = 0.03  # m straight up after releasing
    # m: the retreat first slides the pads this far off the wire they touch (the way the
    # wire pushes them), then rises
    retreat_slide: float = 0.015
    # m of path arc (from the entry) where the pressing pass starts and the tuck looks for wire.
    # Not nearer: the clamp holds the wire's first centimetres on the floor, and the entry is
    # at the edge of the WidowX AI's tool-down reach, where its pad lagged 2-3 cm and rode up.
    # 0.03 -> 0.08, curved, at some step: WidowX 80 -> 90 % held out, 86 -> 93 % validation;
    # UR5 97 -> 99 % and 97 -> 98 % (docs/experts.md, "The WidowX AI's servos").
    press_from: float = 0.08
    press_clearance: float = 0.0015  # m: pad bottom above the wall tops where it cannot fit
    # m: pad bottom below a seated wire's top where it fits.  Not more than 0: the arm's
    # position servo pushes on regardless, and 0.5 mm wedged a capsule between the pad and the
    # floor; it sank 5 mm into the channel and shot out, flinging the plug (curved seed 50).
    press_squeeze: float = 0.0
    press_margin: float = 0.0005  # m: the pad's footprint stays this far inside the walls
    press_window: float = 0.006  # m of arc: the pad rises this far before a misfit
    press_stop: float = 0.005  # m of arc before the channel's end where the pass ends
    press_needed: float = 0.003  # m: a wire point this far above resting calls for pressing
    press_hover: float = 0.02  # m: pad bottoms above the press height before coming down
    # m: farther than this (horizontally) from the pass's start, the pads travel press_travel
    # above the wall tops
    press_travel_reach: float = 0.01
    press_travel: float = 0.04  # m: pad bottoms above the wall tops while travelling
    press_open: float = 0.04  # m: pad gap while pressing (the other pad passes beside)
    press_speed: float = 0.005  # m per step along the path (slower where the pad turns)
    # m: the pad's goal slows down while the pad is farther behind it.  Not 8 mm: the slow
    # arms' pads lag 1-2 cm wherever they drag the wire, and the slowed goal then used up the
    # time a third pass needs (docs/experts.md, "Three pressing passes").
    press_lag: float = 0.02
    press_lag_slowdown: float = 0.25  # speed factor then
    # m: while the goal is slowed, it also rises this much.  A pad stalled on the wire presses
    # it hard and drags it along by friction (the wire behind the pad was pulled up off the
    # floor); raised, it presses less and slides on over the wire.  WidowX AI, curved, at the
    # end / at some step: tuning 90 / 92 -> 99 / 100 %, validation 93 / 93 -> 96 / 97 %
    # (docs/experts.md, "The pad's goal raised while it lags").
    press_lag_lift: float = 0.006
    # The pad's yaw follows the channel's heading averaged over this much arc either side, so
    # it turns gradually through the bends (it fits within ~16 deg of the local heading).
    press_turn_window: float = 0.02  # m of arc
    # The pad turns only as far as it must: its yaw stays within this angle of the channel's
    # heading (a dead band; smaller bends need no turn at all).
    press_yaw_slack: float = math.radians(8.0)
    press_turn_rate: float = 0.008  # rad per step at most (the controller's limit is 0.01)
    final_retreat: float = 0.05  # m straight up after the pressing pass
    # Direction of each pressing pass (+1: from the entry towards the end, -1: back from the
    # end); a pass starts only while a wire point still rides high.  Three: a wire that
    # sprang out again behind the pad gets a third pass where the episode leaves time for it
    # (with ``press_lag`` 2 cm; curved, validation, at the end / at some step: UR5 95 / 97 ->
    # 99 / 99 %, Panda 93 / 96 -> 95 / 98 %, WidowX AI 86 / 91 -> 93 / 93 %; docs/experts.md).
    press_directions: tuple[int, ...] = (1, 1, 1)
    # A pass after the first covers only the stretch where the wire still rides high, from
    # press_lead_in of arc before its first raised point to press_lead_out past its last (a
    # whole second pass rarely fitted in the episode), clipped to the first pass's span.
    press_lead_in: float = 0.04  # m of arc
    press_lead_out: float = 0.02  # m of arc
    # Tuck (before the pressing pass): where the released wire has sprung out sideways over
    # the walls, a pad comes down beside it and pushes it back over the channel.
    tuck: bool = True
    tuck_outside: float = 0.004  # m: wire centre this far outside the inner wall calls for it
    tuck_margin: float = 0.003  # m: pad face this far beyond the wire where it comes down
    tuck_speed: float = 0.003  # m per step across the channel
    max_grasp_retries: int = 2
    seed: int = 0  # diversity (settle delay, lay slow-down)
    # wire model -> {field: value} replacing the fields above for that wire (``WIRE_SETTINGS``)
    wire_settings: dict = field(default_factory=lambda: copy.deepcopy(WIRE_SETTINGS))

    def for_wire(self, model: str) -> SeatingExpertConfig:
        """This configuration with ``wire_settings[model]`` applied (and no table left)."""
        return dataclasses.replace(self, wire_settings={}, **self.wire_settings.get(model, {}))

    def __post_init__(self) -> None:
        if not self.press_directions or any(d not in (-1, 1) for d in self.press_directions):
            raise ValueError(
                "SeatingExpertConfig.press_directions must be a non-empty tuple of +1 (entry to "
                f"end) and -1 (end to entry), got {self.press_directions!r}"
            )
        owner = "SeatingExpertConfig"
        for name in (
            "approach_speed",
            "descend_speed",
            "lift_speed",
            "carry_speed",
            "lay_speed",
            "place_speed",
            "press_speed",
            "press_turn_rate",
            "pre_open",
            "release_open",
            "press_open",
        ):
            validation.positive(owner, name, getattr(self, name))
        validation.positive(owner, "press_lag_slowdown", self.press_lag_slowdown)
        validation.in_range(owner, "press_lag_slowdown", self.press_lag_slowdown, 0.0, 1.0)
        slowdown = self.lay_slowdown
        pair = isinstance(slowdown, (tuple, list)) and len(slowdown) == 2
        if not pair or not (
            0
            < validation.finite(owner, "lay_slowdown", slowdown[0])
            <= validation.finite(owner, "lay_slowdown", slowdown[1])
        ):
            raise ValueError(
                f"{owner}.lay_slowdown must be (low, high) with 0 < low <= high, got {slowdown!r}"
            )
        for name in (
            "hover",
            "grasp_height",
            "lift",
            "lay_from",
            "lay_height",
            "place_above",
            "retreat",
            "press_from",
            "press_clearance",
            "press_margin",
            "press_window",
            "press_stop",
            "press_needed",
            "press_hover",
            "press_travel_reach",
            "press_travel",
            "press_lag",
            "press_lag_lift",
            "press_turn_window",
            "press_yaw_slack",
            "final_retreat",
            "place_stall_distance",
            "press_lead_in",
            "press_lead_out",
            "retreat_slide",
            "tuck_outside",
            "tuck_margin",
        ):
            validation.non_negative(owner, name, getattr(self, name))
        for name in ("lay_wall_clearance", "lay_table_clearance"):
            if getattr(self, name) is not None:
                validation.non_negative(owner, name, getattr(self, name))
        validation.non_negative(owner, "lay_wall_reach", self.lay_wall_reach)
        # the pads' long side has no front: a plug's axis lies at most 90 deg from it
        validation.in_range(owner, "grasp_yaw_free", self.grasp_yaw_free, 0.0, math.pi / 2)
        # Either sign: below (+) or above (-) a seated wire's top.
        validation.finite(owner, "press_squeeze", self.press_squeeze)
        validation.positive(owner, "tuck_speed", self.tuck_speed)
        validation.boolean(owner, "tuck", self.tuck)
        validation.mapping(owner, "wire_settings", self.wire_settings)
        fields = {f.name for f in dataclasses.fields(self)} - {"wire_settings"}
        for model, settings in self.wire_settings.items():
            validation.one_of(owner, "wire_settings", model, WIRE_MODELS.names())
            validation.mapping(owner, f"wire_settings[{model!r}]", settings)
            for name in settings:
                validation.one_of(owner, f"wire_settings[{model!r}]", name, sorted(fields))
            try:
                self.for_wire(model)  # validates the values
            except (ValueError, TypeError) as err:
                raise ValueError(f"{owner}.wire_settings[{model!r}]: {err}") from None
        validation.at_least_int(owner, "place_stall_steps", self.place_stall_steps, 1)
        for name in ("settle_steps", "settle_jitter", "max_grasp_retries"):
            validation.at_least_int(owner, name, getattr(self, name), 0)
        validation.at_least_int(owner, "seed", self.seed, 0)


PHASES = (
    Phase("approach", pos_tol=0.004, dwell=1, timeout=150),
    Phase("descend", pos_tol=0.002, dwell=2, timeout=60),
    Phase("settle", pos_tol=np.inf, rot_tol=np.inf, dwell=1, timeout=60),
    Phase("close", pos_tol=np.inf, rot_tol=np.inf, dwell=4, timeout=40),
    Phase("lift", pos_tol=0.004, dwell=1, timeout=60),
    Phase("carry", pos_tol=0.004, dwell=2, timeout=150),
    Phase("lay", pos_tol=np.inf, rot_tol=np.inf, dwell=1, timeout=200),
    Phase("place", pos_tol=0.002, dwell=4, timeout=60),
    Phase("release", pos_tol=np.inf, rot_tol=np.inf, dwell=3, timeout=30),
    Phase("retreat", pos_tol=0.01, dwell=1, timeout=40),
    Phase("tuck_approach", pos_tol=0.004, dwell=1, timeout=80),
    Phase("tuck_descend", pos_tol=0.002, dwell=2, timeout=40),
    Phase("tuck_push", pos_tol=0.002, dwell=1, timeout=40),
    Phase("tuck_retreat", pos_tol=0.01, dwell=1, timeout=40),
    Phase("press_approach", pos_tol=0.004, dwell=1, timeout=80),
    Phase("press_descend", pos_tol=0.002, dwell=2, timeout=40),
    Phase("press", pos_tol=np.inf, rot_tol=np.inf, dwell=1, timeout=200),
    Phase("press_retreat", pos_tol=0.01, dwell=1, timeout=40),
    Phase("done"),
)


@EXPERTS.register("seating")
class SeatingExpert(ScriptedExpert):
    """Vectorized scripted expert for the seating task (N environments, N = 1 for one env).

    ``reset(env_ids)`` after the environments are reset (a vector env's autoreset included);
    ``act()`` returns the (N, 7) ``cartesian`` actions for the current states.
    """

    PHASES = PHASES

    def __init__(self, env_or_envs, config=None, seed: int | None = None) -> None:
        # Every environment of one expert has the same wire model: its settings apply.
        config = config or self.config_class()
        wire = unwrap_envs(env_or_envs)[0].task.assembly.wire.config.model
        super().__init__(env_or_envs, config.for_wire(wire), seed)

    SNAPSHOTS = (
        ("grasp_pos", (3,)),
        ("lift_from", (3,)),
        ("hold_pos", (3,)),
        ("press_end", (3,)),
        ("slide_dir", (3,)),
        ("start_rot", (3, 3)),
        ("grasp_yaw", (1,)),
    )
    CONTROL = "cartesian"
    TASK = "seating"
    config_class = SeatingExpertConfig

    def _init_state(self) -> None:
        self.rng = np.random.default_rng(self.config.seed)
        self.grasp_retries = np.zeros(self.num_envs, int)
        self.settle_needed = np.zeros(self.num_envs, int)
        self.lay_speed = np.zeros(self.num_envs)
        self.lay_arc = np.zeros(self.num_envs)  # arc of the channel the plug has been laid to
        self.press_arc = np.zeros(self.num_envs)  # arc the pressing pad has reached
        self.press_count = np.zeros(self.num_envs, int)  # pressing passes started
        # arc span (from, to) of the raised wire a later pass covers (NaN: the whole channel)
        self.raised_span = np.full((self.num_envs, 2), np.nan)
        self._profiles: list = [None] * self.num_envs
        self.tuck_arc = np.zeros(self.num_envs)  # arc of the channel where the tuck pushes
        self.tuck_from = np.zeros((self.num_envs, 3))  # world pad-bottom start of the push
        self.tuck_pad = np.zeros(self.num_envs, int)  # the pad that pushes (robot.pad_geom_names)

    def _reset_state(self, mask) -> None:
        cfg, count = self.config, int(mask.sum())
        self.grasp_retries[mask] = 0
        self.lay_arc[mask] = 0.0
        self.press_arc[mask] = 0.0
        self.press_count[mask] = 0
        self.raised_span[mask] = np.nan
        for i in np.flatnonzero(mask):
            self._profiles[i] = None
        self.settle_needed[mask] = cfg.settle_steps + self.rng.integers(
            0, cfg.settle_jitter + 1, count
        )
        self.lay_speed[mask] = cfg.lay_speed / self.rng.uniform(*cfg.lay_slowdown, count)

    # -- frames ------------------------------------------------------------------------------
    def _tcp(self, i):
        env = self.envs[i]
        return env.robot.tcp_pose_base(env.model, env.data)

    def _wire_end(self, i):
        """Base-frame end point of the wire, on the plug's axis end_gap behind its origin."""
        assembly = self.envs[i].task.assembly
        pos, rot = assembly.plug_pose(self.envs[i].data)
        return self._to_base(i, pos - assembly.wire.end_gap * rot[:, 0])

    def _held(self, i) -> bool:
        env = self.envs[i]
        task = env.task
        return all(task.pad_contacts(env.model, env.data, task.held_contacts))

    # -- the channel's path --------------------------------------------------------------------
    def _path(self, i):
        """(M, 3) world points along the channel centre at floor height, extended by the
        task's ``plug_lead`` past its end, and their arc (M,)."""
        task = self.envs[i].task
        placed = task.placed
        line = placed.config.centerline(samples_per_segment=40)
        c, s = math.cos(placed.yaw), math.sin(placed.yaw)
        world = np.column_stack(
            [
                c * line[:, 0] - s * line[:, 1] + placed.pos[0],
                s * line[:, 0] + c * line[:, 1] + placed.pos[1],
                line[:, 2] + placed.pos[2],
            ]
        )
        tangent = world[-1] - world[-2]
        world = np.vstack([world, world[-1] + task.plug_lead * tangent / norm(tangent)])
        return world, arc_lengths(world)

    def _path_point(self, i, s: float, height: float) -> np.ndarray:
        """Base-frame point ``height`` above the channel floor at arc ``s`` of its path."""
        world, arc = self._path(i)
        s = float(np.clip(s, 0.0, arc[-1]))
        point = np.array([np.interp(s, arc, world[:, k]) for k in range(3)])
        return self._to_base(i, point + height * UP)

    def _wall_top(self, i) -> float:
        """World height (m) of the channel's wall tops."""
        placed = self.envs[i].task.placed
        return float(placed.pos[2] + placed.config.floor + placed.config.wall_height)

    def _seated_height(self, i) -> float:
        """Wire-centre height above the channel floor when the wire rests on it."""
        return self.envs[i].task.assembly.wire.config.radius + self.config.place_above

    # -- control -------------------------------------------------------------------------------
    def _open_command(self, i, gap: float | None = None) -> float:
        """Gripper command for a pad gap (m; default ``pre_open``), capped at the robot's."""
        env = self.envs[i]
        gap = min(self.config.pre_open if gap is None else gap, env.robot.max_opening)
        return 1.0 - 2.0 * gap / env.robot.max_opening

    def _goals(self, i):
        """(goal TCP position (base frame), goal orientation (base frame; None: hold the
        controller's), max step (m), gripper, own reached flag or None)."""
        cfg, env, fsm = self.config, self.envs[i], self.fsm
        self._start_rot(i)  # captured at the episode's first step
        name = fsm.phases[fsm.phase[i]].name
        up = self._up(i)
        opened = self._open_command(i)
        grasp = fsm.get("grasp_pos")[i]

        if name == "approach":
            if np.isnan(grasp).any():
                self._take_grasp_goal(i)
                grasp = fsm.get("grasp_pos")[i]
        grasp_rot = self._grasp_rot(i)
        if name == "approach":
            return grasp + cfg.hover * up, grasp_rot, cfg.approach_speed, opened, None
        if name == "descend":
            return grasp, grasp_rot, cfg.descend_speed, opened, None
        if name == "settle":  # pads open, arm still: the plug and wire come to rest
            return (
                grasp,
                grasp_rot,
                cfg.descend_speed,
                opened,
                bool(fsm.steps[i] + 1 >= self.settle_needed[i]),
            )
        if name == "close":
            still = abs(env.robot.gripper_velocity(env.model, env.data)) < 0.005
            return grasp, grasp_rot, cfg.descend_speed, 1.0, bool(self._held(i) and still)
        if name == "lift":
            start = fsm.get("lift_from")[i]
            goal = start + (cfg.lift - self._height(i, start)) * up
            return goal, grasp_rot, cfg.lift_speed, 1.0, None

        # From here on the goals place the wire's end; the TCP keeps its offset to it
        # (re-measured each step in the TCP frame: the plug may turn in the pads) and turns
        # so that the pads' long side, along which the plug is held, follows the channel's
        # last segment: the wire leaves the plug along the channel, between the pads.
        tcp, tcp_rot = self._tcp(i)
        rot = self._yawed(i, self._lay_yaw(i)) if cfg.lay_turn else tcp_rot
        turned_back = not cfg.lay_turn and grasp_rot is not None and name == "carry"
        if turned_back:  # turned for the grasp: the carry turns back to the start orientation
            rot = self._start_rot(i)
        offset = matmul(matmul(rot, tcp_rot.T), tcp - self._wire_end(i))
        rot = rot if cfg.lay_turn or turned_back else None
        _, arc = self._path(i)
        lay_start = arc[-1] - cfg.lay_from
        if name == "carry":
            point = self._path_point(i, lay_start, cfg.lay_height)
            return point + offset, rot, cfg.carry_speed, 1.0, self._stalled(i, tcp)
        seated = self._seated_height(i)
        if name == "lay":
            self.lay_arc[i] = min(self.lay_arc[i] + self.lay_speed[i], cfg.lay_from)
            frac = self.lay_arc[i] / cfg.lay_from
            height = cfg.lay_height + frac * (seated - cfg.lay_height)
            point = self._path_point(i, lay_start + self.lay_arc[i], height)
            goal = self._pads_clear(i, point + offset)
            return goal, rot, 2 * cfg.lay_speed, 1.0, bool(frac >= 1.0)
        if name == "place":
            goal = self._pads_clear(i, self._path_point(i, arc[-1], seated) + offset)
            return goal, rot, cfg.place_speed, 1.0, self._stalled(i, tcp)
        hold = fsm.get("hold_pos")[i]
        released = self._open_command(i, cfg.release_open)
        if name == "release":
            gap = env.robot.gripper_opening(env.model, env.data)
            wide = min(cfg.release_open, env.robot.max_opening)
            return hold, None, cfg.place_speed, released, bool(gap > 0.9 * wide)
        if name == "retreat":
            slide = cfg.retreat_slide * fsm.get("slide_dir")[i]
            moved = flat(self._tcp(i)[0] - hold, up)
            if norm(moved) < 0.8 * norm(slide):  # the rest on the way up
                return hold + slide, None, cfg.descend_speed, released, False
            return hold + cfg.retreat * up + slide, None, cfg.descend_speed, released, None
        if name.startswith("tuck_"):
            # The TCP keeps its orientation (no time spent turning): the pad moves as it is.
            opened = self._open_command(i, cfg.press_open)
            push_z = self._wall_top(i) + cfg.press_clearance
            pad = int(self.tuck_pad[i])
            if name == "tuck_approach":
                goal = self.tuck_from[i] + (self._wall_top(i) + cfg.press_travel) * UP
                return self._pad_to_tcp_now(i, goal, pad), None, cfg.approach_speed, opened, None
            if name == "tuck_descend":
                goal = self.tuck_from[i] + push_z * UP
                return self._pad_to_tcp_now(i, goal, pad), None, cfg.descend_speed, opened, None
            middle = self._press_target(i, self.tuck_arc[i])
            if name == "tuck_push":
                middle[2] = push_z
                tcp = self._pad_to_tcp_now(i, middle, pad)
                return tcp, None, cfg.tuck_speed, opened, self._stalled(i, self._tcp(i)[0])
            middle[2] = self._wall_top(i) + cfg.press_travel
            return self._pad_to_tcp_now(i, middle, pad), None, cfg.approach_speed, opened, None
        if name in ("press_approach", "press_descend", "press"):
            start, stop = self._press_span(i)
            opened = self._open_command(i, cfg.press_open)
            if name == "press_approach":
                target = self._press_target(i, start) + cfg.press_hover * UP
                # Travel with the pads above the walls (and the released plug beside them);
                # come down only over the pass's start.
                tcp_world = env.data.site_xpos[env.task.tcp_site]
                if norm((target - tcp_world)[:2]) > cfg.press_travel_reach:
                    target[2] = max(target[2], self._wall_top(i) + cfg.press_travel)
                tcp, rot = self._pad_to_tcp(i, target, self._press_yaw(i, start))
                return tcp, rot, cfg.approach_speed, opened, None
            if name == "press_descend":
                target = self._press_target(i, start)
                tcp, rot = self._pad_to_tcp(i, target, self._press_yaw(i, start))
                return tcp, rot, cfg.descend_speed, opened, None
            # The pad's goal slows down while the pad lags behind it: a lagging pad that
            # chased a goal further ahead would cut the bends into the walls.
            lag = self._pad_target_world(i) - self._press_target(i, self.press_arc[i])
            slow = norm(lag[:2]) > cfg.press_lag
            done = self._advance_press(i, start, stop, cfg.press_lag_slowdown if slow else 1.0)
            target = self._press_target(i, self.press_arc[i])
            if slow:
                target[2] += cfg.press_lag_lift
            tcp, rot = self._pad_to_tcp(i, target, self._press_yaw(i, self.press_arc[i]))
            return tcp, rot, 3 * cfg.press_speed, opened, done
        # press_retreat / done: the pads keep their gap (a pressing pad opening beside the
        # wall would push into it).
        gap = cfg.press_open if self.press_count[i] or name == "press_retreat" else None
        gap = cfg.release_open if gap is None else gap
        if name == "press_retreat":  # straight up to the travel height: another pass may follow
            return (
                fsm.get("press_end")[i],
                None,
                cfg.approach_speed,
                self._open_command(i, gap),
                None,
            )
        goal = hold + (cfg.retreat + cfg.final_retreat) * up
        return goal, None, cfg.descend_speed, self._open_command(i, gap), None

    def _pads_clear(self, i, tcp_goal) -> np.ndarray:
        """Base-frame TCP goal (of the lay and the place) raised, if need be, so that both
        pads' bottom faces stay ``lay_table_clearance`` above the table, and each pad whose
        face lies over the channel, walls included (or within ``lay_wall_reach`` of it), at
        the goal or now, keeps it ``lay_wall_clearance`` above the wall tops.  Why: a pad
        pushed down onto a wall or the table pries the shut gripper open (docs/experts.md)."""
        cfg, env = self.config, self.envs[i]
        if cfg.lay_wall_clearance is None and cfg.lay_table_clearance is None:
            return tcp_goal
        origin, base = self._base(i)
        goal_world = origin + matmul(base, tcp_goal)
        tcp_world = env.data.site_xpos[env.task.tcp_site]
        tcp_rot = env.data.site_xmat[env.task.tcp_site].reshape(3, 3)
        lift = 0.0
        for pad in (0, 1):
            offset, (half_long, half_short), long = self._pad_frame(i, pad)
            centre = matmul(tcp_rot, offset)
            along = horizontal(matmul(tcp_rot, long), UP)
            across = cross(UP, along)
            # A grid over the bottom face: a 3 mm wall can cross the pad between its corners.
            face = np.array(
                [
                    centre[:2] + a * half_long * along[:2] + c * half_short * across[:2]
                    for a in np.linspace(-1.0, 1.0, 6)
                    for c in (-1.0, 0.0, 1.0)
                ]
            )
            bottom = goal_world[2] + centre[2]
            if cfg.lay_table_clearance is not None:
                lift = max(lift, TABLE_Z + cfg.lay_table_clearance - bottom)
            if cfg.lay_wall_clearance is None:
                continue
            at_goal_or_now = np.vstack([face + goal_world[:2], face + tcp_world[:2]])
            if self._over_channel(i, at_goal_or_now, cfg.lay_wall_reach).any():
                lift = max(lift, self._wall_top(i) + cfg.lay_wall_clearance - bottom)
        return tcp_goal + lift * self._up(i)

    def _wire_push(self, i) -> np.ndarray:
        """Base-frame horizontal unit vector (zeros if none): the way the wire pushes the pads
        it touches (a released wire that springs against a pad rides up with it)."""
        env = self.envs[i]
        pads = env.task.pads[0] | env.task.pads[1]
        push = contact_push(env.data, pads, env.task.assembly.wire_contacts)
        return horizontal(matmul(self._base(i)[1].T, push), self._up(i))

    def _stalled(self, i, tcp) -> bool | None:
        """True once the TCP has stayed within ``place_stall_distance`` for
        ``place_stall_steps`` steps of the current phase (the place: the plug rests on the
        board; the tuck's push: the wire will go no farther; the carry: the arm's servos yield
        to the wire's pull a few millimetres short of the goal, as the WidowX AI's did, which
        then waited out the 150-step timeout); None otherwise (the pose and dwell decide)."""
        cfg = self.config
        still = self._steps_still(i, tcp, cfg.place_stall_distance)
        return True if still >= cfg.place_stall_steps else None

    # -- the pressing pass ---------------------------------------------------------------------
    def _press_span(self, i) -> tuple[float, float]:
        """(start, stop) arc of the current pressing pass, in its direction."""
        cfg = self.config
        _, arc = self._path(i)
        entry_side = cfg.press_from
        end_side = arc[-1] - self.envs[i].task.plug_lead - cfg.press_stop
        direction = cfg.press_directions[min(self.press_count[i], len(cfg.press_directions) - 1)]
        raised = self.raised_span[i]
        if self.press_count[i] and not np.isnan(raised).any():
            entry_side = max(entry_side, min(raised[0] - cfg.press_lead_in, end_side))
            end_side = min(end_side, max(raised[1] + cfg.press_lead_out, entry_side))
        return (entry_side, end_side) if direction > 0 else (end_side, entry_side)

    def _start_rot(self, i) -> np.ndarray:
        """Base-frame TCP orientation of the episode's start (pointing down, pads closing along
        the base y axis): every phase but the pressing pass holds it, and the pad's yaw turns
        from it.  Captured at the expert's first step of the episode."""
        rot = self.fsm.snapshots["start_rot"][i]
        if np.isnan(rot).any():
            rot[:] = self._ctl_target(i)[1]
        return rot

    def _yawed(self, i, yaw: float) -> np.ndarray:
        """Base-frame TCP orientation: the start one turned by ``yaw`` (rad, counter-clockwise
        seen from above) about the vertical."""
        up = self._up(i)
        return matmul(axis_angle_to_mats((yaw * up)[None])[0], self._start_rot(i))

    def _pad_frame(self, i, pad: int = 0):
        """The pressing pad (``pad``: the first of ``robot.pad_geom_names`` by default) in the
        TCP frame: its bottom centre's offset from the TCP (3,) (it changes with the pad gap),
        the half extents (long, short) of its bottom face and the direction of its long side
        (3,)."""
        env = self.envs[i]
        model, data = env.model, env.data
        gid = model.geom(env.robot.pad_geom_names[pad]).id
        pad_rot = data.geom_xmat[gid].reshape(3, 3)
        size = model.geom_size[gid]
        tcp_world = data.site_xpos[env.task.tcp_site]
        tcp_rot = data.site_xmat[env.task.tcp_site].reshape(3, 3)
        bottom = data.geom_xpos[gid] - size[2] * UP
        long = int(np.argmax(size[:2]))
        halves = (float(size[long]), float(size[1 - long]))
        return matmul(tcp_rot.T, bottom - tcp_world), halves, matmul(tcp_rot.T, pad_rot[:, long])

    def _pad_target_world(self, i, pad: int = 0) -> np.ndarray:
        """World centre of the pressing pad's (``pad``'s) bottom face now."""
        env = self.envs[i]
        offset, _, _ = self._pad_frame(i, pad)
        tcp_rot = env.data.site_xmat[env.task.tcp_site].reshape(3, 3)
        return env.data.site_xpos[env.task.tcp_site] + matmul(tcp_rot, offset)

    def _pad_to_tcp(self, i, pad_target_world, yaw: float):
        """Base-frame TCP goal position and orientation (turned by ``yaw``) that bring the
        pressing pad's bottom centre to a world point."""
        rot = self._yawed(i, yaw)
        offset, _, _ = self._pad_frame(i)
        tcp_world = pad_target_world - matmul(matmul(self._base(i)[1], rot), offset)
        return self._to_base(i, tcp_world), rot

    def _pad_to_tcp_now(self, i, pad_target_world, pad: int = 0) -> np.ndarray:
        """Base-frame TCP goal that brings ``pad``'s bottom centre to a world point with the
        TCP's orientation as it is now."""
        env = self.envs[i]
        tcp_world = env.data.site_xpos[env.task.tcp_site]
        pad_now = self._pad_target_world(i, pad)
        return self._to_base(i, pad_target_world - (pad_now - tcp_world))

    def _press_target(self, i, s: float):
        """World point for the pad's bottom centre at arc ``s``: on the path, at the seated
        wire's top where the pad fits between the walls, else just above the wall tops."""
        world, arc = self._path(i)
        heights = self._press_heights(i)
        s = float(np.clip(s, 0.0, arc[-1]))
        point = np.array([np.interp(s, arc, world[:, k]) for k in range(3)])
        return point + np.interp(s, arc, heights) * UP

    def _press_yaw(self, i, s: float) -> float:
        """The pad's yaw (rad, from the start orientation) at arc ``s`` of the path."""
        _, arc = self._path(i)
        return float(np.interp(s, arc, self._press_profile(i)[1]))

    def _advance_press(self, i, start: float, stop: float, factor: float = 1.0) -> bool:
        """Move the pad one step along the path towards ``stop``: ``press_speed``, slower where
        its yaw profile turns by more than ``press_turn_rate`` in that step (the turn keeps up
        with the slide).  Returns whether the pass has arrived."""
        cfg = self.config
        _, arc = self._path(i)
        yaws = self._press_profile(i)[1]
        ahead = np.sign(stop - start)
        here = self.press_arc[i]
        middle = (arc[1:] + arc[:-1]) / 2
        lo, hi = sorted((here, here + ahead * cfg.press_speed))
        near = (middle >= lo - 0.002) & (middle <= hi + 0.002)
        slope = np.abs(np.diff(yaws)) / np.maximum(np.diff(arc), 1e-9)
        steepest = float(slope[near].max()) if near.any() else 0.0
        step = cfg.press_speed * factor
        if steepest * step > cfg.press_turn_rate:
            step = cfg.press_turn_rate / steepest
        self.press_arc[i] = here + ahead * step
        if ahead * (self.press_arc[i] - stop) >= 0:
            self.press_arc[i] = stop
            return True
        return False

    def _pad_turns(self, i, headings: np.ndarray) -> np.ndarray:
        """Yaws (rad, from the start orientation) that turn the pads' long side onto world xy
        ``headings`` (K,): the side has no front, so at most 90 deg either way, continuous
        along the sequence."""
        _, _, long_tcp = self._pad_frame(i)
        start_long = matmul(matmul(self._base(i)[1], self._start_rot(i)), long_tcp)
        start_heading = math.atan2(start_long[1], start_long[0])
        return np.unwrap((headings - start_heading + np.pi / 2) % np.pi - np.pi / 2, period=np.pi)

    def _lay_yaw(self, i) -> float:
        """Yaw (rad, from the start orientation) that lines the pads' long side up with the
        channel's last segment."""
        world, _ = self._path(i)
        end = world[-1] - world[-2]
        return float(self._pad_turns(i, np.array([math.atan2(end[1], end[0])]))[0])

    def _press_heights(self, i) -> np.ndarray:
        """(M,) pad-bottom heights above the floor along the path (``_press_profile``)."""
        return self._press_profile(i)[0]

    def _press_profile(self, i):
        """Pad-bottom heights above the floor (M,) and pad yaws (M,) along the path, computed
        once per episode from the channel's geometry and the pad's box in the model.

        The yaw turns the pad's long side from its start heading onto the channel's heading
        averaged over ``press_turn_window`` of arc either side (the pad is symmetric end to
        end: at most 90 deg either way); the pad goes down to a seated wire's top wherever its
        whole footprint, so turned, lies between the walls (``press_margin`` inside) within
        ``press_window`` of arc, and passes above the wall tops elsewhere."""
        if self._profiles[i] is not None:
            return self._profiles[i]
        cfg, task = self.config, self.envs[i].task
        channel = task.placed.config
        world, arc = self._path(i)
        step = np.diff(world[:, :2], axis=0)
        heading = arctan2(step[:, 1], step[:, 0])
        heading = np.append(heading, heading[-1])
        _, (half_long, half_short), long_tcp = self._pad_frame(i)
        start_long = matmul(matmul(self._base(i)[1], self._start_rot(i)), long_tcp)
        start_heading = math.atan2(start_long[1], start_long[0])
        turn = self._pad_turns(i, heading)
        # Dead band along the pass's first direction (entry to end): the yaw only follows
        # the heading once that is more than press_yaw_slack away.
        lazy = np.empty_like(turn)
        yaw = 0.0
        for k, h in enumerate(turn):
            yaw = lazy[k] = float(np.clip(yaw, h - cfg.press_yaw_slack, h + cfg.press_yaw_slack))
        yaws = np.array([lazy[np.abs(arc - a) <= cfg.press_turn_window].mean() for a in arc])
        along = np.column_stack([np.cos(start_heading + yaws), np.sin(start_heading + yaws)])
        across = np.column_stack([-along[:, 1], along[:, 0]])
        # (M, 4, 2) footprint corners: each path point +/- the half extents along both sides.
        corners = np.stack(
            [
                world[:, :2] + sa * half_long * along + sc * half_short * across
                for sa in (-1, 1)
                for sc in (-1, 1)
            ],
            axis=1,
        )
        fits = np.array([self._between_walls(i, c, cfg.press_margin).all() for c in corners])
        # Stay high wherever the pad would not fit within press_window of arc.
        blocked = ~fits
        near = np.zeros_like(blocked)
        for k in np.flatnonzero(blocked):
            near |= np.abs(arc - arc[k]) <= cfg.press_window
        wire = task.assembly.wire.config
        deep = 2 * wire.radius - cfg.press_squeeze
        high = channel.wall_height + cfg.press_clearance
        self._profiles[i] = (np.where(near, high, deep), yaws)
        return self._profiles[i]

    def _segment_coords(self, i, xy):
        """Per channel segment: world xy points (K, 2) in its frame, (along (K,), across (K,)),
        and the channel's config."""
        placed = self.envs[i].task.placed
        local = placed.to_local(np.column_stack([xy, np.zeros(len(xy))]))
        cfg = placed.config
        coords = []
        for start, heading in cfg.segment_frames():
            d = local[:, :2] - start
            u = d[:, 0] * math.cos(heading) + d[:, 1] * math.sin(heading)
            v = -d[:, 0] * math.sin(heading) + d[:, 1] * math.cos(heading)
            coords.append((u, v))
        return coords, cfg

    def _between_walls(self, i, xy, margin: float) -> np.ndarray:
        """(K,) whether world xy points lie over the channel floor, ``margin`` inside the
        walls."""
        coords, cfg = self._segment_coords(i, xy)
        inside = np.zeros(len(xy), bool)
        for u, v in coords:
            inside |= (
                (u >= -margin)
                & (u <= cfg.segment_length + margin)
                & (np.abs(v) <= cfg.inner_width / 2 - margin)
            )
        return inside

    def _over_channel(self, i, xy, reach: float) -> np.ndarray:
        """(K,) whether world xy points lie over the channel, walls included (their rounded
        ends reach ``wall / 2`` past a segment's), or within ``reach`` of it."""
        coords, cfg = self._segment_coords(i, xy)
        over = np.zeros(len(xy), bool)
        ends = cfg.wall / 2 + reach
        for u, v in coords:
            over |= (
                (u >= -ends)
                & (u <= cfg.segment_length + ends)
                & (np.abs(v) <= cfg.inner_width / 2 + cfg.wall + reach)
            )
        return over

    @staticmethod
    def _nearest_path_index(path: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(K,) index of the path point nearest (horizontally) to each of ``points`` (K, 3)."""
        return norm(points[:, None, :2] - path[None, :, :2], axis=2).argmin(1)

    def _needs_tuck(self, i) -> bool:
        """Whether an inner wire point over the board beside the channel lies more than
        ``tuck_outside`` (per wire: ``WIRE_SETTINGS``) outside its inner walls, high
        enough that a pad just above the wall tops pushes it (its centre above the pad's
        bottom), while the plug lies below the pads' bottoms: keeps the channel arc where the
        farthest such point lies (``tuck_arc``), the pad that pushes (``tuck_pad``) and its
        start beside the wire (``tuck_from``)."""
        cfg, env = self.config, self.envs[i]
        task = env.task
        pads = [self._pad_target_world(i, pad) for pad in (0, 1)]
        plug_z = task.assembly.plug_pose(env.data)[0][2]
        if plug_z > min(pad[2] for pad in pads):
            # The plug, flung up as the wire sprang, hangs between the open fingers: a tuck
            # would drag it along and fold the wire into a hairpin (validation seeds 2002,
            # 2025).  The pressing pass travels away from it instead.
            return False
        world = env.wire_points()[1:-1]
        path, arc = self._path(i)
        end = arc[-1] - task.plug_lead - cfg.press_stop
        nearest = self._nearest_path_index(path, world)
        offset = world[:, :2] - path[nearest, :2]
        distance = norm(offset, axis=1)
        push_z = self._wall_top(i) + cfg.press_clearance
        radius = task.assembly.wire.config.radius
        half_width = task.placed.config.inner_width / 2
        outside = cfg.tuck_outside
        ok = (
            (distance > half_width + outside)
            & (world[:, 2] > push_z)
            & (arc[nearest] > cfg.press_from)
            & (arc[nearest] < end)
        )
        if not ok.any():
            return False
        k = int(np.flatnonzero(ok)[np.argmax(distance[ok])])
        side = offset[k] / distance[k]
        # The pushing pad is the one on the channel's side of the TCP: the other one then
        # comes down farther out, and the wire never lies between the open pads (it was caught
        # there and lifted into a hairpin).
        tcp = env.data.site_xpos[task.tcp_site][:2]
        inward = [-dot(pad[:2] - tcp, side) for pad in pads]
        self.tuck_pad[i] = int(np.argmax(inward))
        _, (_, half_short), _ = self._pad_frame(i, int(self.tuck_pad[i]))
        reach = distance[k] + radius + half_short + cfg.tuck_margin
        self.tuck_arc[i] = arc[nearest[k]]
        self.tuck_from[i] = np.append(path[nearest[k], :2] + reach * side, 0.0)
        return True

    def _needs_pressing(self, i) -> bool:
        """Whether any inner point of the wire short of the channel's end rides higher than
        ``press_needed`` above a wire resting on the channel floor (the expert's own check;
        the success flag is not read).  Past the end the wire rises to the plug's exit
        anyway: no pass can lower it there.  Keeps the arc span of those points along the
        path (``raised_span``) for a later pass."""
        env = self.envs[i]
        placed = env.task.placed
        world = env.wire_points()[1:-1]
        points = placed.to_local(world)
        start, heading = placed.config.segment_frames()[-1]
        along = dot(points[:, :2] - start, np.array([math.cos(heading), math.sin(heading)]))
        short = along < placed.config.segment_length
        rest = placed.config.floor + env.task.assembly.wire.config.radius
        raised = short & (points[:, 2] > rest + self.config.press_needed)
        if not raised.any():
            return False
        path, arc = self._path(i)
        nearest = self._nearest_path_index(path, world[raised])
        self.raised_span[i] = arc[nearest].min(), arc[nearest].max()
        return True

    def _take_grasp_goal(self, i) -> None:
        """Grasp at the middle of the plug's tail (its ``grasp_site``), TCP ``grasp_height``
        above the table: the pads (closing along the base y axis) squeeze the tail across."""
        cfg, env = self.config, self.envs[i]
        site = env.data.site_xpos[env.task.assembly.grasp_site]
        grasp = self._to_base(i, site)
        up = self._up(i)
        grasp = grasp + (cfg.grasp_height - self._height(i, grasp)) * up
        self.fsm.snapshots["grasp_pos"][i] = grasp
        self.fsm.snapshots["grasp_yaw"][i] = self._grasp_turn(i)

    def _grasp_turn(self, i) -> float:
        """Yaw (rad, about the vertical, from the start orientation) that brings the plug's axis
        within ``grasp_yaw_free`` of the pads' long side, along which they hold it; 0 when it
        lies there."""
        axis = self.envs[i].task.assembly.plug_pose(self.envs[i].data)[1][:, 0]
        angle = float(self._pad_turns(i, np.array([math.atan2(axis[1], axis[0])]))[0])
        excess = abs(angle) - self.config.grasp_yaw_free
        return math.copysign(excess, angle) if excess > 0 else 0.0

    def _grasp_rot(self, i) -> np.ndarray | None:
        """Goal orientation of the grasp phases: None (hold) unless the grasp turns."""
        yaw = float(self.fsm.get("grasp_yaw")[i, 0])
        return self._yawed(i, yaw) if np.isfinite(yaw) and yaw != 0.0 else None

    def _on_advance(self, advanced: np.ndarray, before: np.ndarray) -> None:
        fsm, cfg = self.fsm, self.config
        idx = fsm.index
        for i in np.flatnonzero(advanced):
            left = before[i]
            if left == idx("close"):
                fsm.snapshots["lift_from"][i] = self._tcp(i)[0]
            elif left == idx("lift"):
                if not self._held(i) and self.grasp_retries[i] < cfg.max_grasp_retries:
                    self.grasp_retries[i] += 1
                    self._take_grasp_goal(i)
                    fsm.goto("approach", np.eye(self.num_envs, dtype=bool)[i])
            elif left == idx("carry"):
                self.lay_arc[i] = 0.0
            elif left == idx("press_descend"):
                self.press_arc[i] = self._press_span(i)[0]
            elif left == idx("press"):
                self.press_count[i] += 1
                rise = self._wall_top(i) + cfg.press_travel - self._pad_target_world(i)[2]
                up = self._up(i)
                fsm.snapshots["press_end"][i] = self._tcp(i)[0] + rise * up
            elif left == idx("press_retreat"):
                more = self.press_count[i] < len(cfg.press_directions)
                if more and self._needs_pressing(i):
                    fsm.goto("press_approach", np.eye(self.num_envs, dtype=bool)[i])
            elif left == idx("place"):
                fsm.snapshots["hold_pos"][i] = self._tcp(i)[0]
            elif left == idx("release"):
                fsm.snapshots["slide_dir"][i] = self._wire_push(i)
            elif left == idx("retreat"):
                one = np.eye(self.num_envs, dtype=bool)[i]
                if cfg.tuck and self._needs_tuck(i):
                    fsm.goto("tuck_approach", one)
                else:
                    fsm.goto("press_approach" if self._needs_pressing(i) else "done", one)
            elif left == idx("tuck_retreat") and not self._needs_pressing(i):
                fsm.goto("done", np.eye(self.num_envs, dtype=bool)[i])
