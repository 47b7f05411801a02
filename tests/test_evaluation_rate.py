"""Learned policies run at the rate their dataset was recorded at, and torch on one thread.

The truth: scripted-expert episodes collected with ``wirecraft collect``.  Each episode's own
``action`` column, replayed through the adapter that LeRobot policies use
(``DatasetActionPolicy``: queried at frame boundaries, each action held for 60 / fps control
steps) by the evaluation's own loop, seats the plug wherever the expert seated it.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from wirecraft.datasets.collect import CollectSettings, collect
from wirecraft.datasets.writer import load_dataset
from wirecraft.envs.env import CONTROL_HZ
from wirecraft.envs.env import steps_per_frame as frame_steps
from wirecraft.evaluation import protocol
from wirecraft.evaluation.policies import DatasetActionPolicy
from wirecraft.evaluation.protocol import EpisodeSpec, EvalConfig, run_chunk, run_evaluation

FPS = 30
# Seed 0's first four episodes: replayed one control step per frame (twice the recorded
# speed, the adapter before it read the dataset's fps) two of them miss the port.
SETTINGS = CollectSettings(
    task="insertion", env_kwargs={"connector": "ethernet"}, image_size=32, fps=FPS, seed=0
)


class ReplayPolicy(DatasetActionPolicy):
    """The dataset's recorded actions in order, one per frame (the last one held after the
    end), through the same adapter code a LeRobot policy goes through."""

    def __init__(self, env, actions, fps):
        super().__init__(env, fps)
        self.actions = np.asarray(actions, dtype=float)
        self.queries: list[tuple[int, np.ndarray]] = []  # (control step, observed state)

    def reset(self, env_ids=None) -> None:
        super().reset(env_ids)
        self.queries = []

    def frame_actions(self, obs) -> np.ndarray:
        del obs  # state observations: the dataset's state is read off the environment
        env = self.envs[0]
        self.queries.append((self._step, env.robot.dataset_state(env.model, env.data)))
        frame = min(len(self.queries) - 1, len(self.actions) - 1)
        return self.actions[frame][None]


@pytest.fixture(scope="module")
def episodes(tmp_path_factory):
    """(seed, states, actions, expert seated) of each collected episode."""
    root = tmp_path_factory.mktemp("rate") / "ds"
    report = collect(SETTINGS, root, 4, workers=0, progress_bar=False)
    assert report.saved == 4
    table = load_dataset(root).hf_dataset.with_format("arrow")[:]
    index = table.column("episode_index").to_numpy()
    columns = {
        key: np.stack(table.column(key).to_numpy(zero_copy_only=False)).reshape(len(index), -1)
        for key in ("observation.state", "action", "seed", "insert_success")
    }
    result = []
    for e in np.unique(index):
        rows = np.flatnonzero(index == e)
        result.append(
            (
                int(columns["seed"][rows[0]][0]),
                columns["observation.state"][rows],
                columns["action"][rows],
                bool(columns["insert_success"][rows].any()),
            )
        )
    return result


def replay(seed, actions, fps, frames):
    """Run the recorded actions through the evaluation loop; (summary, the policy)."""
    config = EvalConfig(
        task="insertion",
        policy=ReplayPolicy,
        env_kwargs={"connector": "ethernet", "control": "joint"},
        horizon=frames * (CONTROL_HZ // FPS),  # the recorded episode's length
        batch=1,
        policy_kwargs={"actions": np.asarray(actions).tolist(), "fps": fps},
    )
    [result] = run_chunk(config, [EpisodeSpec(0, 0, seed)])
    _, policy = protocol.environment_and_policy(config)
    return result.summary, policy


def test_frame_steps_need_a_divisor_of_the_control_rate():
    assert frame_steps(30) == 2 and frame_steps(60) == 1 and frame_steps(10.0) == 6
    for bad in (7, 0, -30, 120, True, "30"):
        with pytest.raises(ValueError, match="must divide the 60 Hz"):
            frame_steps(bad)


def test_recorded_actions_replayed_at_the_dataset_rate_seat_every_plug(episodes):
    k = CONTROL_HZ // FPS
    seated = []
    for seed, states, actions, expert_seated in episodes:
        assert expert_seated
        summary, policy = replay(seed, actions, FPS, len(actions))
        seated.append(summary["insert_success"])
        # Queried at each frame boundary only, on the state the recorder sampled there.
        steps = [step for step, _ in policy.queries]
        assert steps == list(range(0, k * len(actions), k))
        assert np.allclose(policy.queries[0][1], states[0], atol=1e-6)  # right after reset
    assert seated == [True] * len(episodes)


def test_one_control_step_per_frame_plays_too_fast_and_misses(episodes):
    """What the adapter did before it held each action for its frame: the check above
    fails without the fix."""
    seated = [
        replay(seed, a, CONTROL_HZ, len(a))[0]["insert_success"] for seed, _, a, _ in episodes
    ]
    assert not all(seated)


class ThreadProbe:
    """A factory policy that reports torch's thread count as its phase name."""

    control = None

    def __init__(self, env):
        import torch

        from wirecraft.experts.fsm import unwrap_envs

        self.torch = torch
        self.envs = unwrap_envs(env)

    def reset(self, env_ids=None):
        del env_ids

    def act(self, obs):
        del obs
        return np.zeros((len(self.envs), self.envs[0].action_space.shape[0]))

    def phase_names(self):
        return [f"threads={self.torch.get_num_threads()}"] * len(self.envs)


@pytest.mark.parametrize("workers", [1, 2])
def test_torch_runs_on_one_thread_per_process_stepping_the_policy(workers):
    torch = pytest.importorskip("torch")
    before = torch.get_num_threads()
    payload = run_evaluation(
        "insertion", ThreadProbe, seeds=1, episodes=2, workers=workers, episode_seconds=0.05,
        progress=False,
    ).payload  # fmt: skip
    assert [ep["final_phase"] for ep in payload["episodes"]] == ["threads=1"] * 2
    assert torch.get_num_threads() == before  # this process's setting is given back
    if workers == 1 and before > 1:
        payload = run_evaluation(
            "insertion", ThreadProbe, seeds=1, episodes=1, episode_seconds=0.05,
            progress=False, torch_threads=0,
        ).payload  # fmt: skip
        assert payload["episodes"][0]["final_phase"] == f"threads={before}"
    with pytest.raises(ValueError, match="torch_threads"):
        run_evaluation("insertion", "zero", torch_threads=-1)


def test_a_scripted_evaluation_does_not_import_torch():
    code = (
        "import sys\n"
        "from wirecraft.evaluation import evaluate\n"
        "evaluate('insertion', 'scripted', seeds=1, episodes=1, episode_seconds=0.05,"
        " progress=False)\n"
        "print('torch' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
