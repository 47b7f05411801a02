"""Failure labels: each produced by a constructed scenario (a policy built to fail one way),
plus the labelling rules on hand-made traces."""

from __future__ import annotations

import math

import numpy as np
import pytest

from wirecraft.evaluation import diagnostics, protocol
from wirecraft.evaluation.policies import ScriptedPolicy
from wirecraft.experts import InsertionExpert, InsertionExpertConfig
from wirecraft.experts.fsm import unwrap_envs
from wirecraft.tasks.insertion import InsertionOptions
from wirecraft.tasks.insertion import metrics as insertion_metrics

PLAIN = InsertionExpertConfig(diversity=False)  # no pick-and-drop or pauses: one clear story


def _rotation(axis: int, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    if axis == 0:
        return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


class _ExpertVariant(ScriptedPolicy):
    """The insertion expert with one thing changed (``expert_class``)."""

    control = "cartesian"
    expert_class = InsertionExpert

    def __init__(self, env):
        self.expert = self.expert_class(env, PLAIN)


class RolledExpert(InsertionExpert):
    """Turns the plug 90 degrees about the socket axis before inserting."""

    def _plug_goal_rot(self, i):
        return super()._plug_goal_rot(i) @ _rotation(0, math.pi / 2)


class TiltedExpert(InsertionExpert):
    """Inserts with the plug's axis tilted 8 degrees (under the orientation tolerance)."""

    def _plug_goal_rot(self, i):
        return super()._plug_goal_rot(i) @ _rotation(1, math.radians(8.0))


class ShiftedExpert(InsertionExpert):
    """Aims the tip 7 mm below the socket axis (more than clearance + 1 mm)."""

    def _tcp_for_tip(self, i, tip, plug_rot):
        return super()._tcp_for_tip(i, tip - 0.007 * plug_rot[:, 2], plug_rot)


class WireGraspExpert(InsertionExpert):
    """Grasps the wire 5 cm behind the plug instead of the plug."""

    def _take_grasp_goal(self, i):
        super()._take_grasp_goal(i)
        view = self.views[i]
        axis = view.plug_rot[:, 0] - np.dot(view.plug_rot[:, 0], view.up) * view.up
        self.fsm.snapshots["grasp_pos"][i] -= 0.05 * axis / np.linalg.norm(axis)


class YawPolicy(_ExpertVariant):
    expert_class = RolledExpert


class JamPolicy(_ExpertVariant):
    expert_class = TiltedExpert


class LateralPolicy(_ExpertVariant):
    expert_class = ShiftedExpert


class WrongPartPolicy(_ExpertVariant):
    expert_class = WireGraspExpert


class PlainExpertPolicy(_ExpertVariant):
    pass


class DropPolicy(_ExpertVariant):
    """The expert until the plug is lifted, then the pads open in mid-air for good."""

    def act(self, obs):
        actions = self.expert.act(obs)
        fsm = self.expert.fsm
        late = fsm.phase >= fsm.index("pre_insert")
        actions[late] = 0.0
        actions[late, -1] = -1.0
        return actions


class RamPolicy:
    """Drives the closed gripper into the port's stand, never grasping."""

    control = "cartesian"

    def __init__(self, env):
        self.envs = unwrap_envs(env)

    def reset(self, env_ids=None):
        del env_ids

    def act(self, obs):
        actions = np.zeros((len(self.envs), 7))
        for i, env in enumerate(self.envs):
            task, data = env.task, env.data
            goal = data.site_xpos[task.entry_site] + [0.0, 0.03, -0.02]  # behind the mouth
            base = data.site_xmat[task.base_site].reshape(3, 3)
            delta = base.T @ (goal - data.site_xpos[task.tcp_site])
            actions[i, :3] = np.clip(delta / 0.01, -1.0, 1.0)
            actions[i, -1] = 1.0
        return actions


class BlowUpPolicy:
    """Holds still, then writes an absurd joint speed into the state: the step diverges."""

    control = None

    def __init__(self, env):
        self.envs = unwrap_envs(env)
        self.steps = 0

    def reset(self, env_ids=None):
        self.steps = 0

    def act(self, obs):
        self.steps += 1
        if self.steps == 3:
            for env in self.envs:
                env.data.qvel[:] = 1e4
        return np.zeros((len(self.envs), self.envs[0].action_space.shape[0]))


def _episode(policy, seconds: float, **env_kwargs) -> dict:
    payload = protocol.evaluate(
        "insertion",
        policy,
        seeds=1,
        episodes=1,
        episode_seconds=seconds,
        progress=False,
        **env_kwargs,
    )
    return payload["episodes"][0]


# -- constructed scenarios -------------------------------------------------------------------------
def test_a_gripper_that_never_closes_is_no_grasp():
    episode = _episode("zero", 1.0)
    assert (episode["success"], episode["failure"]) == (False, "no_grasp")


def test_forcing_divergence_is_diverged():
    episode = _episode(BlowUpPolicy, 0.5)
    assert episode["failure"] == "diverged" and episode["diverged"]
    assert episode["steps"] == 3


def test_ramming_the_port_stand_is_fixture_collision():
    episode = _episode(RamPolicy, 2.0)
    assert episode["failure"] == "fixture_collision"
    assert episode["max_robot_fixture_force"] >= diagnostics.COLLISION_FORCE
    assert "no_grasp" in episode["events"]  # recorded, but the collision came first


def test_grasping_the_wire_instead_of_the_plug_is_wrong_part():
    episode = _episode(WrongPartPolicy, 4.0)
    assert episode["failure"] == "wrong_part"


def test_releasing_the_plug_in_mid_air_is_dropped():
    episode = _episode(DropPolicy, 5.0)
    assert episode["failure"] == "dropped"


def test_an_expert_cut_short_while_carrying_is_timeout():
    episode = _episode(PlainExpertPolicy, 3.0)
    assert episode["failure"] == "timeout"
    assert episode["final_phase"] in ("lift", "pre_insert")


@pytest.mark.slow
def test_a_plug_turned_90_degrees_is_yaw_misaligned():
    episode = _episode(YawPolicy, 8.0)
    assert episode["reach_success"] and not episode["insert_success"]
    assert episode["failure"] == "yaw_misaligned"


@pytest.mark.slow
def test_a_plug_aimed_off_the_axis_is_laterally_misaligned():
    episode = _episode(LateralPolicy, 8.0)
    assert episode["reach_success"] and not episode["insert_success"]
    assert episode["failure"] == "lateral_misaligned"


@pytest.mark.slow
def test_a_tilted_plug_in_a_tight_socket_is_jammed():
    episode = _episode(JamPolicy, 8.0, clearance=0.0005)
    assert episode["reach_success"] and not episode["insert_success"]
    assert episode["failure"] == "jammed"
    assert 0.0 < episode["max_insertion_depth"] < 0.012  # stuck part-way in
    assert episode["max_insertion_force"] >= insertion_metrics.JAM_FORCE


# -- the rules on hand-made traces -----------------------------------------------------------------
def _trace(task: str, steps: int = 100, **columns) -> dict:
    trace = {c: np.zeros(steps) for c in diagnostics.columns(task)}
    trace["min_bend_radius"][:] = np.inf
    if task == "routing":
        trace["clip_distance"][:] = 0.2
    for key, value in columns.items():
        trace[key] = np.asarray(value, float)
    return trace


def _held(steps: int, start: int, stop: int) -> np.ndarray:
    held = np.zeros(steps)
    held[start:stop] = 1.0
    return held


def test_a_brush_of_the_pads_is_not_a_grasp():
    ctx = diagnostics.LabelContext("insertion", False, InsertionOptions(clearance=0.003))
    brief = _trace("insertion", held=_held(100, 10, 12))
    assert diagnostics.label_failure(brief, ctx) == "no_grasp"
    firm = _trace("insertion", held=_held(100, 10, 10 + diagnostics.HOLD_STEPS))
    assert diagnostics.label_failure(firm, ctx) == "dropped"


def test_routing_labels():
    ctx = diagnostics.LabelContext("routing", False)
    held = _held(100, 20, 100)
    assert diagnostics.label_failure(_trace("routing"), ctx) == "no_grasp"
    plug = _trace("routing", wrong_held=_held(100, 5, 50))
    assert diagnostics.label_failure(plug, ctx) == "wrong_part"
    assert diagnostics.label_failure(_trace("routing", held=held), ctx) == "timeout"
    near = np.full(100, 0.2)
    near[60:70] = 0.01
    brought = _trace("routing", held=held, clip_distance=near)
    assert diagnostics.label_failure(brought, ctx) == "clip_missed"
    lost = _trace("routing", held=_held(100, 20, 50))
    assert diagnostics.label_failure(lost, ctx) == "dropped"


def test_seating_labels():
    ctx = diagnostics.LabelContext("seating", False)
    laid = np.linspace(0.0, 0.5, 100)
    assert diagnostics.label_failure(_trace("seating", held=_held(100, 20, 90)), ctx) == "dropped"
    seated = _trace("seating", held=_held(100, 20, 90), fraction_inside=laid)
    assert diagnostics.label_failure(seated, ctx) == "not_seated"


def test_a_collision_after_a_misaligned_attempt_does_not_hide_the_misalignment():
    steps = 100
    reach = _held(steps, 40, 100)
    lateral = np.full(steps, 0.02)
    collision = np.zeros(steps)
    collision[80:] = 50.0  # the pads hit the port after the failed attempt
    ctx = diagnostics.LabelContext("insertion", False, InsertionOptions(clearance=0.003))
    trace = _trace(
        "insertion",
        held=_held(steps, 10, 100),
        reach=reach,
        lateral_error=lateral,
        robot_fixture_force=collision,
        insertion_depth=np.linspace(-0.05, 0.0, steps),
    )
    label, events = diagnostics.diagnose(trace, ctx)
    assert label == "lateral_misaligned"
    assert "fixture_collision" in events
    collision[:] = 0.0
    collision[20] = 50.0  # before the port was reached: the collision is the failure
    trace["robot_fixture_force"] = collision
    assert diagnostics.label_failure(trace, ctx) == "fixture_collision"


def test_every_label_is_documented_per_task():
    for task in ("insertion", "routing", "seating"):
        labels = diagnostics.labels_for(task)
        assert labels[0] == "diverged" and labels[-1] == "timeout"
        assert {"no_grasp", "dropped", "wrong_part", "fixture_collision"} <= set(labels)
    assert "jammed" in diagnostics.labels_for("insertion")
    assert "clip_missed" in diagnostics.labels_for("routing")
    assert "not_seated" in diagnostics.labels_for("seating")
    from pathlib import Path

    doc = (Path(__file__).parents[1] / "docs" / "evaluation.md").read_text()
    for label in diagnostics.all_labels():
        assert f"`{label}`" in doc
