"""A task family is one unit: a family defined here, outside the package, registers and runs
through make, make_vec, ``wirecraft eval --policy random``, ``wirecraft collect`` (with its own
expert) and ``wirecraft report`` without any edit to shared code; and every registered family
provides every hook the shared code calls."""

from __future__ import annotations

import dataclasses
import json
import math
from typing import ClassVar

import gymnasium as gym
import numpy as np
import pytest

import wirecraft
from wirecraft.assets.assembly import WireAssembly
from wirecraft.assets.connectors import make_connector
from wirecraft.cli_args import number
from wirecraft.evaluation import diagnostics
from wirecraft.experts import EXPERTS, expert_class
from wirecraft.numerics import norm
from wirecraft.tasks import TASKS, Task, TaskMetrics, TaskOptions, metrics_of, option
from wirecraft.tasks.metrics import final

TOY = "push_to_mark"
TOY_ID = "WireCraftTest/PushToMark-v0"


@dataclasses.dataclass(frozen=True)
class PushOptions(TaskOptions):
    family: ClassVar[str] = TOY

    mark_x: float = option(0.0, "x of the mark on the table (m)", parse=number(-0.3, 0.3))
    tolerance: float = option(0.02, "success radius (m)", parse=number(0, low_open=True))

    def __post_init__(self) -> None:
        if not self.tolerance > 0:
            raise ValueError(f"{TOY}.tolerance must be > 0, got {self.tolerance!r}")


class PushTask(Task):
    """Push the plug (lying on the table) onto a mark: a family written for this test."""

    name = TOY
    gym_id = TOY_ID
    default_control = "cartesian"
    default_weights = {"closer": 1.0, "action": -0.01}
    Options = PushOptions
    demo_options = {"mark_x": 0.05}

    @property
    def episode_seconds(self) -> float:
        return 0.5

    @property
    def instruction(self) -> str:
        return "Push the plug onto the mark."

    def build_scene(self, spec, wire_config) -> None:
        self.assembly = WireAssembly.build(spec, wire_config, make_connector("ethernet"))

    def bind(self, model, robot) -> None:
        super().bind(model, robot)
        self.held_contacts = self.assembly.plug_contacts
        self.fixture_contacts = self.table_geom

    def mark(self) -> np.ndarray:
        return np.array([self.options.mark_x, 0.15, 0.0])

    def initialize_episode(self, model, data, rng) -> None:
        plug = np.array([rng.uniform(-0.1, 0.1), 0.0, 0.02])
        self.assembly.place(model, data, plug, np.array([0.0, 1.0, 0.0]), 0.0)

    def distance_batch(self, frame) -> np.ndarray:
        """(N,) the plug's distance to the mark on the table."""
        return norm((frame.xpos[:, self.assembly.plug_id] - self.mark())[:, :2])

    def observe_batch(self, frame) -> np.ndarray:
        plug = self.to_base_batch(frame, frame.xpos[:, self.assembly.plug_id])
        distance = self.distance_batch(frame)[:, None]
        return np.concatenate([self.robot_state_batch(frame), plug, distance], axis=1)

    def reward_batch(self, frame, trackers, actions) -> dict[str, np.ndarray]:
        return {
            "closer": -self.distance_batch(frame),
            "action": np.sum(np.square(actions), axis=1),
        }

    def evaluate_batch(self, frame, data_of) -> dict[str, np.ndarray]:
        distance = self.distance_batch(frame)
        return {"success": distance <= self.options.tolerance, "mark_distance": distance}


@metrics_of(PushTask)
class PushMetrics(TaskMetrics):
    columns = ("mark_distance",)
    failure_labels = {"short_of_mark": "the plug moved towards the mark but stopped short"}
    trace_plots = (("mark_distance", "distance to the mark (mm)", 1000.0, None),)
    episode_columns = ("final_mark_distance",)

    def at_goal(self, trace, held):
        return np.nan_to_num(trace["mark_distance"], nan=np.inf) < 0.1

    def summarize(self, episode, steps):
        return {"final_mark_distance": final(episode["mark_distance"], steps)}

    def standard_variants(self):
        return [{"mark_x": 0.0}]


@dataclasses.dataclass
class PushExpertConfig:
    seed: int | None = None


class PushExpert:
    """Moves the TCP down and forwards with the gripper open: pushes whatever it meets."""

    CONTROL = "cartesian"
    TASK = TOY
    config_class = PushExpertConfig

    def __init__(self, env_or_envs, config=None, seed=None) -> None:
        del config, seed
        self.num_envs = 1

    def act(self, obs) -> np.ndarray:
        del obs
        return np.array([[0.0, 0.5, -0.5, 0.0, 0.0, 0.0, -1.0]])


@pytest.fixture
def toy_family():
    """Register the toy family and its expert for one test, then remove them."""
    TASKS.register(TOY)(PushTask)
    EXPERTS.register(TOY)(PushExpert)
    try:
        yield TOY
    finally:
        TASKS.unregister(TOY)
        EXPERTS.unregister(TOY)
        gym.registry.pop(TOY_ID, None)


def test_toy_family_runs_through_make_and_make_vec(toy_family):
    env = wirecraft.make(toy_family, mark_x=0.1)
    obs, info = env.reset(seed=3)
    assert env.unwrapped.max_steps == 30  # the family's own episode length
    assert env.spec.id == TOY_ID
    for _ in range(3):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert math.isfinite(reward) and "mark_distance" in info
    env.close()
    env = gym.make(TOY_ID, tolerance=0.5)  # gymnasium's own loader sees the family
    env.reset(seed=0)
    env.close()

    venv = wirecraft.make_vec(toy_family, 2, threads=1, mark_x=0.1)
    obs, _ = venv.reset(seed=[5, 6])
    single = wirecraft.make(toy_family, mark_x=0.1)
    single_obs, _ = single.reset(seed=6)
    np.testing.assert_array_equal(obs[1], single_obs)
    venv.close()
    single.close()
    with pytest.raises(ValueError, match="unknown option 'clearance'"):
        wirecraft.make(toy_family, clearance=0.003)
    with pytest.raises(ValueError, match="tolerance"):
        wirecraft.make(toy_family, tolerance=-1.0)


def test_toy_family_runs_through_eval_collect_and_report(toy_family, tmp_path, capsys):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from wirecraft.cli import main

    out = tmp_path / "eval"
    code = main(
        [
            "eval",
            "--task",
            toy_family,
            "--mark-x",
            "0.05",
            "--policy",
            "random",
            "--seeds",
            "1",
            "--episodes",
            "2",
            "--json",
            str(out / "run.json"),
            "--traces",
            str(out / "traces.parquet"),
            "--report",
            str(tmp_path / "report"),
        ]
    )
    assert code == 0
    payload = json.loads((out / "run.json").read_text())
    assert payload["task"] == toy_family
    assert payload["variant"] == f"{toy_family}/mark_x=0.05/tolerance=0.02"
    assert set(payload["metrics"]) == {"success", "retain_success", "success_at_end"}
    assert len(payload["episodes"]) == 2
    for episode in payload["episodes"]:
        assert "final_mark_distance" in episode
        assert episode["failure"] in [None, *diagnostics.labels_for(toy_family)]
    html = (tmp_path / "report" / "index.html").read_text()
    assert "short_of_mark" in html and "final_mark_distance" in html
    assert len(list((tmp_path / "report" / "plots").glob(f"traces_{toy_family}_*.png"))) == 1
    # another family's flag is refused for this one, naming it
    capsys.readouterr()
    assert main(["eval", "--task", toy_family, "--clearance", "0.002"]) == 2
    assert "--clearance does not apply" in capsys.readouterr().err

    dataset = tmp_path / "demos"
    code = main(
        [
            "collect",
            "--task",
            toy_family,
            "--episodes",
            "2",
            "--image-size",
            "32",
            "--fps",
            "10",
            "--workers",
            "0",
            "--keep-failures",
            "--out",
            str(dataset),
        ]
    )
    assert code == 0
    ds = LeRobotDataset("wirecraft/test", root=dataset)
    assert ds.meta.total_episodes == 2
    assert "success" in ds.features and "reach_success" not in ds.features


@pytest.mark.parametrize("family", TASKS.names())
def test_every_family_provides_every_hook(family):
    """What shared code reads of a family, checked on each registered one."""
    cls = TASKS.get(family)
    assert wirecraft.register_gym_ids()[family] == cls.gym_id
    assert issubclass(cls.Options, TaskOptions) and cls.Options is not TaskOptions
    defaults = cls.Options()  # every option has a default
    assert set(defaults.as_dict()) == set(cls.Options.names())
    for field in dataclasses.fields(cls.Options):
        assert field.metadata.get("help"), f"{family}.{field.name} has no help text"
    assert set(cls.demo_options) <= set(cls.Options.names())
    metrics = cls.metrics
    assert isinstance(metrics, TaskMetrics) and type(metrics) is not TaskMetrics
    assert metrics.success_flags[0] == "success"
    assert metrics.columns and not set(metrics.columns) & set(diagnostics.COMMON_COLUMNS)
    assert metrics.failure_labels
    assert not set(metrics.failure_labels) & set(diagnostics.EARLY_LABELS)
    assert {p[0] for p in metrics.trace_plots} <= set(diagnostics.columns(family))
    for variant in metrics.standard_variants():
        cls.Options.build(variant)
    assert type(metrics).at_goal is not TaskMetrics.at_goal
    assert expert_class(family).CONTROL
    # the trace of a held, never-at-goal episode is labelled by the shared rules
    trace = {c: np.zeros(20) for c in diagnostics.columns(family)}
    trace["held"][:] = 1.0
    for column in metrics.columns:
        trace[column][:] = np.nan
    label = diagnostics.label_failure(trace, diagnostics.LabelContext(family, False))
    assert label == "timeout"


def test_a_robot_workspace_refuses_what_is_not_a_number():
    from wirecraft.assets.robots.base import Workspace

    assert Workspace().max_x == math.inf
    for bad in (float("nan"), "far", None, True):
        with pytest.raises(ValueError, match="max_x"):
            Workspace(max_x=bad)
