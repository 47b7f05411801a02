"""RL baselines (wirecraft.rl): configuration checks, the rsl-rl adapter against the vector env
it wraps, short real training runs of PPO, SACfD and vision PPO with checkpoint round trips
(actions recomputed by hand from the saved tensors) and resumption."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

import wirecraft
from wirecraft.rl import RUN_FILE, load_policy, train
from wirecraft.rl.common import EpisodeTracker, ProgressTable, final_observations
from wirecraft.rl.config import PPOConfig, SACfDConfig, VisionPPOConfig, parse_override

SHORT = {"episode_seconds": 0.1}  # 6 control steps per episode


def _elu(x):
    return np.where(x > 0, x, np.expm1(np.minimum(x, 0)))


def _mlp_numpy(state: dict, prefix: str, x: np.ndarray, last_activation: bool = False):
    """Linear layers ``prefix.<i>.weight/bias`` with ELU between them, in numpy."""
    indices = sorted({int(k[len(prefix) :].split(".")[0]) for k in state if k.startswith(prefix)})
    for n, i in enumerate(indices):
        w = state[f"{prefix}{i}.weight"].double().numpy()
        b = state[f"{prefix}{i}.bias"].double().numpy()
        x = x @ w.T + b
        if n < len(indices) - 1 or last_activation:
            x = _elu(x)
    return x


def _scalars(run_dir, prefix: str) -> dict[str, list[float]]:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(run_dir))
    acc.Reload()
    return {
        tag: [e.value for e in acc.Scalars(tag)]
        for tag in acc.Tags()["scalars"]
        if tag.startswith(prefix)
    }


# -- configuration ------------------------------------------------------------------------------
def test_configs_carry_the_reference_defaults_and_reject_bad_values():
    ppo = PPOConfig()
    assert ppo.actor_hidden_dims == (256, 128, 64) and ppo.activation == "elu"
    assert (ppo.clip_param, ppo.entropy_coef, ppo.value_loss_coef) == (0.2, 0.01, 1.0)
    assert (ppo.learning_rate, ppo.desired_kl, ppo.num_steps_per_env) == (5e-4, 0.01, 128)
    assert (ppo.num_mini_batches, ppo.num_learning_epochs, ppo.max_grad_norm) == (8, 5, 1.0)
    vision = VisionPPOConfig()
    assert (vision.clip_param, vision.desired_kl, vision.entropy_coef) == (0.1, 0.005, 0.0)
    assert (vision.value_loss_coef, vision.learning_rate, vision.init_std) == (0.3, 1e-4, 0.05)
    assert (vision.num_envs, vision.max_iterations, vision.queries_per_camera) == (64, 600, 8)
    sac = SACfDConfig()
    assert (sac.batch_size, sac.replay_per_env, sac.warmup_steps) == (256, 8000, 5000)
    assert (sac.target_entropy, sac.initial_alpha) == (-7.0, 0.1)
    # the reference's 0.01, applied to Isaac Lab's rewards weighted by the 1/60 s step period
    assert sac.reward_scale == pytest.approx(0.01 / 60)
    with pytest.raises(ValueError, match="clip_param"):
        PPOConfig(clip_param=1.5)
    with pytest.raises(ValueError, match="actor_hidden_dims"):
        PPOConfig(actor_hidden_dims=())
    with pytest.raises(ValueError, match="demo_ratio"):
        SACfDConfig(demo_ratio=2.0)
    with pytest.raises(ValueError, match="token_dim"):
        VisionPPOConfig(token_dim=10, attention_heads=4)
    with pytest.raises(ValueError, match="unknown setting"):
        ppo.updated(no_such_field=1)
    with pytest.raises(ValueError, match="backend must be 'cpu' or 'warp'"):
        PPOConfig(backend="gpu")


def test_bc_weight_follows_the_annealing_schedule():
    cfg = SACfDConfig()  # 2.5 -> 0.5 between 80k and 250k env steps
    assert cfg.bc_weight(0) == cfg.bc_weight(80_000) == 2.5
    assert cfg.bc_weight(165_000) == pytest.approx(1.5)
    assert cfg.bc_weight(250_000) == cfg.bc_weight(10**7) == 0.5


def test_overrides_parse_to_the_field_types():
    cfg = PPOConfig()
    assert parse_override("actor_hidden_dims=64,32", cfg) == ("actor_hidden_dims", (64, 32))
    assert parse_override("learning_rate=1e-3", cfg) == ("learning_rate", 1e-3)
    assert parse_override("obs_normalization=false", cfg) == ("obs_normalization", False)
    with pytest.raises(ValueError, match="unknown setting"):
        parse_override("lr=1", cfg)
    with pytest.raises(ValueError, match="cannot read"):
        parse_override("num_envs=many", cfg)
    # Any config dataclass, e.g. an expert's (the eval_*_expert benchmarks' --set): a tuple
    # of floats reads as floats, one of ints as ints.
    from wirecraft.experts import InsertionExpertConfig

    expert = InsertionExpertConfig()
    assert parse_override("drop_height=0.03,0.05", expert) == ("drop_height", (0.03, 0.05))
    assert parse_override("close_pause=0,5", expert) == ("close_pause", (0, 5))
    with pytest.raises(ValueError, match="cannot read"):
        parse_override("close_pause=0.5,1", expert)
    # a tuple of names reads as names (the config itself checks them)
    import dataclasses

    from wirecraft.experts.seating import SeatingExpertConfig

    @dataclasses.dataclass
    class Named:
        wires: tuple[str, ...] = ("articulated",)

    assert parse_override("wires=articulated, rod", Named()) == ("wires", ("articulated", "rod"))
    seating = SeatingExpertConfig()
    # a table reads as a JSON object
    table = parse_override('wire_settings={"fem": {"tuck": false}}', seating)
    assert table == ("wire_settings", {"fem": {"tuck": False}})
    with pytest.raises(ValueError, match="cannot read 'fem' as dict"):
        parse_override("wire_settings=fem", seating)
    # a field that is None now reads as its declared type (``float | None``)
    floorless = SeatingExpertConfig(lay_table_clearance=None)
    assert parse_override("lay_table_clearance=0.001", floorless) == ("lay_table_clearance", 0.001)
    with pytest.raises(ValueError, match="cannot read 'x' as float"):
        parse_override("lay_table_clearance=x", floorless)
    assert parse_override("lay_wall_clearance=none", seating) == ("lay_wall_clearance", None)


# -- the rsl-rl adapter -------------------------------------------------------------------------
class _Recorder:
    """Forwards to a vector env and keeps what its ``reset``/``step`` returned."""

    def __init__(self, venv) -> None:
        self.venv = venv
        self.returned = []

    def __getattr__(self, name):
        return getattr(self.venv, name)

    def reset(self, **kwargs):
        self.returned.append(self.venv.reset(**kwargs))
        return self.returned[-1]

    def step(self, actions):
        self.returned.append(self.venv.step(actions))
        return self.returned[-1]


def test_adapter_matches_the_vector_env_and_flags_time_outs():
    import torch

    from wirecraft.rl.ppo import make_vec_env_adapter

    n, scale = 3, 0.5
    venv = _Recorder(wirecraft.make_vec("insertion", n, threads=1, **SHORT))
    adapter = make_vec_env_adapter(venv, reward_scale=scale, seed=4)
    obs = adapter.get_observations()
    assert obs["policy"].dtype == torch.float32 and tuple(obs["policy"].shape) == (n, 42)
    np.testing.assert_allclose(obs["policy"].numpy(), venv.returned[0][0], rtol=1e-6)
    rng = np.random.default_rng(0)
    saw_time_out = False
    for _ in range(7):
        actions = rng.uniform(-1.5, 1.5, (n, 7))
        obs, rewards, dones, extras = adapter.step(torch.as_tensor(actions))
        env_obs, env_rewards, _, env_truncated, _ = venv.returned[-1]
        np.testing.assert_allclose(obs["policy"].numpy(), env_obs, rtol=1e-6)
        np.testing.assert_allclose(rewards.numpy(), env_rewards * scale, rtol=1e-6)
        np.testing.assert_array_equal(dones.numpy().astype(bool), env_truncated)
        np.testing.assert_array_equal(extras["time_outs"].numpy().astype(bool), env_truncated)
        if env_truncated.any():
            saw_time_out = True
            log = extras["log"]
            assert len(log["Episode/success"]) == int(env_truncated.sum())
            assert set(log["Episode/length"].tolist()) == {6.0}
    assert saw_time_out
    assert adapter.env_steps == 7 * n
    assert adapter.episode_length_buf.tolist() == [1] * n  # 7 steps = one 6-step episode + 1


def test_final_observations_replace_rows_of_finished_envs():
    obs = np.zeros((3, 2))
    final = np.empty(3, dtype=object)
    final[1] = np.array([7.0, 8.0])
    out = final_observations(obs, {"final_obs": final}, np.array([False, True, False]))
    np.testing.assert_array_equal(out, [[0, 0], [7, 8], [0, 0]])
    assert obs[1, 0] == 0  # not modified in place


def test_episode_tracker_sums_each_reward_term_per_episode():
    tracker = EpisodeTracker(2)
    no = np.zeros(2, bool)
    step = {"reward/bring": np.array([1.0, 2.0]), "reward/grasp": np.array([0.5, 0.0])}
    assert tracker.step(np.array([1.5, 2.0]), no, no, step) == []
    records = tracker.step(np.array([1.5, 2.0]), no, np.array([False, True]), step)
    assert len(records) == 1  # only the second environment's episode ended
    assert records[0]["reward/bring"] == 4.0 and records[0]["reward/grasp"] == 0.0
    assert records[0]["return"] == 4.0 and records[0]["length"] == 2
    # The finished environment starts its next episode from zero; the other one carries on.
    records = tracker.step(np.array([1.5, 2.0]), no, np.array([True, True]), step)
    assert [r["reward/bring"] for r in records] == [3.0, 2.0]
    assert [r["reward/grasp"] for r in records] == [1.5, 0.0]


def test_episode_tracker_tells_episodes_started_from_an_expert_state_apart():
    tracker = EpisodeTracker(3)
    no, rewards = np.zeros(3, bool), np.zeros(3)
    assert "expert_start" not in tracker.step(rewards, no, np.ones(3, bool), {})[0]
    tracker.started({"expert_start": np.array([True, False, True])})  # the first reset
    # env 1 ends: its record says fresh; its next episode (restarted from a state) is noted
    ended = np.array([False, True, False])
    records = tracker.step(rewards, no, ended, {"expert_start": np.array([False, True, False])})
    assert [r["expert_start"] for r in records] == [0.0]
    # all end: 0 and 2 began from expert states at the first reset, 1 at the step before
    everyone = np.ones(3, bool)
    records = tracker.step(rewards, no, everyone, {"expert_start": np.zeros(3, bool)})
    assert [r["expert_start"] for r in records] == [1.0, 1.0, 1.0]
    records = tracker.step(rewards, no, everyone, {"expert_start": np.zeros(3, bool)})
    assert [r["expert_start"] for r in records] == [0.0, 0.0, 0.0]


def test_behaviour_clone_init_fits_actions_and_discounted_returns():
    """Synthetic demonstrations with a known answer: actions a linear map of the state, a
    reward of 100 per step (a seated plug pays ~17 after reward_scale), so the return t steps
    before the end of a T-step episode is 100 (1 - gamma^t) / (1 - gamma), up to ~880."""
    from types import SimpleNamespace

    import torch
    from rsl_rl.utils import resolve_class
    from tensordict import TensorDict

    from wirecraft.rl.ppo import behaviour_clone_init, build_actor, runner_config

    torch.manual_seed(0)  # the networks' initial weights
    cfg = PPOConfig(actor_hidden_dims=(32,), critic_hidden_dims=(32,))
    steps, episodes, gamma = 20, 40, 0.9
    gen = torch.Generator().manual_seed(0)
    dim = 6
    obs = 5.0 + 3.0 * torch.rand(steps * episodes, dim, generator=gen)  # far from N(0, 1)
    time_left = torch.arange(steps, 0, -1).repeat(episodes).float()
    obs[:, 0] = time_left  # the critic can tell where in the episode a state is
    mixing = torch.randn(dim, 7, generator=gen) * 0.3
    actions = torch.tanh((obs - 6.5) @ mixing)
    demos = {"observations": obs, "actions": actions, "rewards": torch.full((len(obs), 1), 100.0)}
    critic_cls, critic_kwargs = resolve_class(runner_config(cfg)["critic"])
    example = TensorDict({"policy": obs[:1]}, batch_size=[1])
    critic = critic_cls(example, {"critic": ["policy"]}, "critic", 1, **critic_kwargs)
    actor = build_actor(cfg, dim, 7)
    runner = SimpleNamespace(alg=SimpleNamespace(actor=actor, critic=critic))
    with torch.no_grad():
        before = float(
            torch.nn.functional.mse_loss(actor(TensorDict({"policy": obs}, [len(obs)])), actions)
        )
    losses = behaviour_clone_init(
        runner, demos, episode_steps=steps, gamma=gamma, epochs=150, seed=0, progress=False
    )
    td = TensorDict({"policy": obs}, batch_size=[len(obs)])
    with torch.no_grad():
        after = float(torch.nn.functional.mse_loss(actor(td), actions))
        values = critic(td)[:, 0]
    expected = 100.0 * (1 - gamma**time_left) / (1 - gamma)
    assert after < 0.05 * before and losses["actor"] < 0.05 * before
    # per step of the episode (averaged over the episodes' other features)
    per_step = values.reshape(episodes, steps).mean(0)
    # a warm start, not an exact fit: the shape, and within ~11 % of the range
    assert bool((per_step[:-1] > per_step[1:]).all())  # more time left, more return
    torch.testing.assert_close(per_step, expected[:steps], atol=100.0, rtol=0)
    mean = actor.obs_normalizer._mean[0]
    torch.testing.assert_close(mean, obs.mean(0), rtol=1e-4, atol=1e-4)
    with pytest.raises(ValueError, match="whole 20-step episode"):
        behaviour_clone_init(
            runner,
            {k: v[:10] for k, v in demos.items()},
            episode_steps=steps,
            gamma=gamma,
            epochs=1,
            seed=0,
            progress=False,
        )


def test_rollouts_use_one_torch_thread_and_the_update_keeps_its_threads():
    import types

    import torch

    from wirecraft.rl import ppo

    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        update = lambda: torch.get_num_threads()  # noqa: E731  (reports the threads it ran on)
        runner = types.SimpleNamespace(alg=types.SimpleNamespace(update=update))
        with ppo.single_threaded_rollouts(runner):
            assert torch.get_num_threads() == 1  # rollouts
            assert runner.alg.update() == 2  # the update
            assert torch.get_num_threads() == 1  # back to rollouts
        assert torch.get_num_threads() == 2 and runner.alg.update is update
    finally:
        torch.set_num_threads(before)


def test_demo_mixing_memory_draws_the_demo_ratio():
    import gymnasium as gym
    import torch

    from wirecraft.rl.sacfd import DemoMixingMemory, _memory

    obs_space = gym.spaces.Box(-1, 1, (2,))
    act_space = gym.spaces.Box(-1, 1, (1,))
    demos = _memory(50, 1, obs_space, act_space, replacement=True)
    demos.add_samples(
        observations=torch.ones(50, 2),
        next_observations=torch.ones(50, 2),
        actions=torch.ones(50, 1),
        rewards=torch.ones(50, 1),
        terminated=torch.zeros(50, 1, dtype=torch.bool),
    )
    memory = _memory(20, 2, obs_space, act_space, DemoMixingMemory, demos=demos, demo_ratio=0.25)
    for _ in range(10):
        memory.add_samples(
            observations=torch.zeros(2, 2),
            next_observations=torch.zeros(2, 2),
            actions=torch.zeros(2, 1),
            rewards=torch.zeros(2, 1),
            terminated=torch.zeros(2, 1, dtype=torch.bool),
        )
    obs, states = memory.sample(["observations", "states"], batch_size=16)[0]
    assert states is None
    assert obs.shape == (16, 2) and int(obs[:, 0].sum()) == 4  # a quarter from the demos


# -- training runs ------------------------------------------------------------------------------
PPO_TINY = {
    "num_envs": 3,
    "num_steps_per_env": 8,
    "actor_hidden_dims": (16, 8),
    "critic_hidden_dims": (16,),
    "num_mini_batches": 2,
    "num_learning_epochs": 2,
    "save_interval": 100,
    "threads": 1,
}


@pytest.mark.slow
def test_ppo_trains_saves_loads_and_resumes(tmp_path):
    import torch

    run_dir = tmp_path / "ppo"
    summary = train("ppo", "insertion", SHORT, run_dir, 48, overrides=PPO_TINY, progress=False)
    assert summary["env_steps"] == 48 and summary["latest_checkpoint"] == "checkpoints/model_1.pt"
    run = json.loads((run_dir / RUN_FILE).read_text())
    assert (run["algorithm"], run["control"], run["obs"]["dim"], run["action_dim"]) == (
        "ppo",
        "cartesian",
        42,
        7,
    )
    losses = _scalars(run_dir, "Loss/")
    assert {"Loss/value", "Loss/surrogate", "Loss/entropy"} <= set(losses)
    assert all(math.isfinite(v) for values in losses.values() for v in values)

    # round trip: the loaded policy's actions are the saved actor's mean, by hand
    venv = wirecraft.make_vec("insertion", 2, threads=1, **SHORT)
    obs, _ = venv.reset(seed=1)
    policy = load_policy(run_dir, venv)
    assert policy.control == "cartesian"
    from wirecraft.rl import policy_env_kwargs

    assert policy_env_kwargs(run_dir) == {"control": "cartesian", "obs_mode": "state"}
    state = torch.load(run_dir / "checkpoints/model_1.pt", weights_only=False)["actor_state_dict"]
    mean, std = state["obs_normalizer._mean"].double().numpy(), state["obs_normalizer._std"]
    x = (obs - mean) / (std.double().numpy() + 1e-2)
    expected = np.clip(_mlp_numpy(state, "mlp.", x), -1, 1)
    np.testing.assert_allclose(policy.act(obs), expected, atol=1e-5)
    np.testing.assert_array_equal(
        load_policy(run_dir / "checkpoints/model_1.pt").act(obs), policy.act(obs)
    )
    assert policy.act(obs[0]).shape == (1, 7)

    # the run directory is a policy for the evaluation protocol (wirecraft eval --policy RUN_DIR)
    from wirecraft.evaluation import evaluate

    result = evaluate("insertion", str(run_dir), seeds=1, episodes=2, episode_seconds=0.1)
    assert len(result["episodes"]) == 2
    assert set(result["metrics"]) >= {"success", "reach_success", "insert_success"}

    # resume: iterations 2 and 3 follow the saved ones, normalizer statistics carry over; a
    # row logged after the last checkpoint (a run killed between checkpoints) is redone
    ProgressTable(run_dir / "progress.csv").append({"iteration": 2, "wall_time_s": -1.0})
    train("ppo", "insertion", None, run_dir, steps=96, resume=True, progress=False)
    run = json.loads((run_dir / RUN_FILE).read_text())
    assert run["iterations_done"] == 4 and run["env_steps"] == 96
    assert run["latest_checkpoint"] == "checkpoints/model_3.pt"
    rows = ProgressTable(run_dir / "progress.csv").rows()
    assert [r["iteration"] for r in rows] == [0, 1, 2, 3]
    assert [r["env_steps"] for r in rows] == [24, 48, 72, 96]
    assert min(r["wall_time_s"] for r in rows) >= 0
    first = torch.load(run_dir / "checkpoints/model_1.pt", weights_only=False)
    later = torch.load(run_dir / "checkpoints/model_3.pt", weights_only=False)
    assert later["iter"] == 3
    count = "obs_normalizer.count"
    assert int(later["actor_state_dict"][count]) == 2 * int(first["actor_state_dict"][count])

    # rollouts of the policy as a dataset in the shared schema, source "rl"
    from wirecraft.datasets.schema import SOURCE_KEY, SOURCES
    from wirecraft.datasets.writer import load_dataset
    from wirecraft.rl.record import record_rollouts

    written = record_rollouts(run_dir, tmp_path / "data", 1, image_size=32, progress=False)
    assert written == {"episodes": 1, "frames": 3, "successes": 0}  # 6 steps at 30 fps
    dataset = load_dataset(tmp_path / "data")
    assert dataset.num_episodes == 1 and dataset.num_frames == 3
    assert {int(dataset[i][SOURCE_KEY]) for i in range(3)} == {SOURCES.index("rl")}
    # the same from the command line: wirecraft collect --policy RUN
    from wirecraft.cli import main as cli_main

    argv = ["collect", "--policy", str(run_dir), "--episodes", "2", "--image-size", "32"]
    assert cli_main([*argv, "--seed", "4", "--out", str(tmp_path / "cli")]) == 0
    dataset = load_dataset(tmp_path / "cli")
    assert dataset.num_episodes == 2
    assert {int(dataset[i][SOURCE_KEY]) for i in range(6)} == {SOURCES.index("rl")}
    for refused, flag in (
        (["--task", "routing"], "--task"),
        (["--connector", "usb_a"], "--connector"),
        (["--workers", "2"], "--workers"),
        (["--resume"], "--resume"),
    ):
        assert cli_main([*argv, *refused, "--out", str(tmp_path / "no")]) == 2, flag
        assert not (tmp_path / "no").exists()
    assert cli_main(["collect", "--policy", str(tmp_path), "--out", str(tmp_path / "no")]) == 2

    with pytest.raises(ValueError, match="--resume"):
        train("ppo", "insertion", None, run_dir, steps=96, progress=False)
    with pytest.raises(ValueError, match="keeps its settings"):
        train("ppo", "insertion", None, run_dir, overrides={"seed": 5}, resume=True)
    with pytest.raises(ValueError, match="control"):
        load_policy(run_dir, wirecraft.make("insertion", control="joint"))

    # the run records the state revision it was trained on; another revision does not load
    from wirecraft.tasks import STATE_REVISION

    assert run["state_revision"] == STATE_REVISION
    assert run["versions"]["wirecraft"] == wirecraft.__version__
    for old in (STATE_REVISION - 1, None):  # None: a run from before revisions were recorded
        if old is None:
            del run["state_revision"]
        else:
            run["state_revision"] = old
        (run_dir / RUN_FILE).write_text(json.dumps(run))
        with pytest.raises(ValueError, match=f"trained on state revision {old or 1};"):
            load_policy(run_dir)
        with pytest.raises(ValueError, match="state revision"):
            train("ppo", "insertion", None, run_dir, steps=144, resume=True, progress=False)


def test_source_commit_names_the_checkout_and_marks_uncommitted_changes(tmp_path):
    import subprocess

    from wirecraft.provenance import source_commit as _source_commit

    assert _source_commit(tmp_path) is None  # not a git checkout

    def git(*args):
        return subprocess.run(
            ["git", "-C", str(tmp_path), "-c", "user.name=t", "-c", "user.email=t@t", *args],
            check=True,
            capture_output=True,
            text=True,
        ).stdout.strip()

    git("init", "-q")
    (tmp_path / "__init__.py").write_text("x = 1\n")
    git("add", "__init__.py")
    git("commit", "-q", "-m", "first")
    head = git("rev-parse", "HEAD")
    assert _source_commit(tmp_path) == head
    (tmp_path / "notes.txt").write_text("untracked files do not count")
    assert _source_commit(tmp_path) == head
    (tmp_path / "__init__.py").write_text("x = 2\n")
    assert _source_commit(tmp_path) == head + "+dirty"
    # a package installed (untracked) inside someone else's repository is not their commit
    installed = tmp_path / "venv" / "site-packages" / "wirecraft"
    installed.mkdir(parents=True)
    (installed / "__init__.py").write_text("")
    assert _source_commit(installed) is None


@pytest.mark.slow
def test_sacfd_trains_with_demonstrations_saves_loads_and_resumes(tmp_path, sac_tiny):
    import torch

    run_dir = tmp_path / "sac"
    settings = sac_tiny
    summary = train("sacfd", "insertion", SHORT, run_dir, 20, overrides=settings, progress=False)
    assert summary["env_steps"] == 20 and summary["latest_checkpoint"] == "checkpoints/agent_10.pt"
    demos = torch.load(run_dir / "demos.pt", weights_only=True)
    assert demos["observations"].shape == (24, 42) and demos["actions"].shape == (24, 7)
    assert demos["actions"].abs().max() <= 1.0  # the expert's (clipped) actions
    losses = _scalars(run_dir, "Loss")
    assert {"Loss / Policy loss", "Loss / Critic loss", "Loss / BC loss"} <= set(losses)
    assert all(math.isfinite(v) for values in losses.values() for v in values)

    venv = wirecraft.make_vec("insertion", 2, threads=1, **SHORT)
    obs, _ = venv.reset(seed=2)
    policy = load_policy(run_dir, venv)
    saved = torch.load(run_dir / "checkpoints/agent_10.pt", weights_only=False)
    scaler = saved["observation_preprocessor"]
    mean = scaler["running_mean"].numpy()
    x = np.clip((obs - mean) / (np.sqrt(scaler["running_variance"].numpy()) + 1e-8), -5, 5)
    hidden = _mlp_numpy(saved["policy"], "net.", x, last_activation=True)
    w, b = saved["policy"]["mean_head.weight"], saved["policy"]["mean_head.bias"]
    expected = np.tanh(hidden @ w.double().numpy().T + b.double().numpy())
    np.testing.assert_allclose(policy.act(obs), expected, atol=1e-5)
    assert "entropy" in saved  # the learned temperature is checkpointed

    table = ProgressTable(run_dir / "progress.csv")
    table.append({"iteration": 15, "env_steps": 30, "wall_time_s": -1.0})  # after the checkpoint
    train("sacfd", "insertion", None, run_dir, steps=40, resume=True, progress=False)
    run = json.loads((run_dir / RUN_FILE).read_text())
    assert run["env_steps"] == 40 and run["latest_checkpoint"] == "checkpoints/agent_20.pt"
    assert [r["env_steps"] for r in table.rows()] == [10, 20, 30, 40]
    assert min(r["wall_time_s"] for r in table.rows()) >= 0


VISION_TINY = {
    "num_envs": 2,
    "num_steps_per_env": 4,
    "actor_hidden_dims": (32,),
    "critic_hidden_dims": (16,),
    "num_mini_batches": 2,
    "num_learning_epochs": 1,
    "queries_per_camera": 2,
    "token_dim": 8,
    "attention_heads": 2,
    "bc_transitions": 24,
    "bc_epochs": 8,
    "bc_batch_size": 12,
    "bc_learning_rate": 3e-3,
    "threads": 1,
}


@pytest.mark.slow
def test_vision_ppo_clones_the_expert_then_fine_tunes(tmp_path):
    run_dir = tmp_path / "vision"
    settings = VISION_TINY
    env_kwargs = {**SHORT, "image_size": 24}
    train("vision-ppo", "insertion", env_kwargs, run_dir, 8, overrides=settings, progress=False)
    run = json.loads((run_dir / RUN_FILE).read_text())
    assert run["env_kwargs"]["obs_mode"] == "state_rgb"
    bc = run["behaviour_cloning"]
    assert bc["teacher"] == "scripted expert" and bc["transitions"] == 24
    assert bc["epoch_losses"][-1] < bc["epoch_losses"][0]
    losses = _scalars(run_dir, "Loss/")
    assert all(math.isfinite(v) for values in losses.values() for v in values)

    env = wirecraft.make("insertion", obs_mode="rgb", image_size=24, **SHORT)
    obs, _ = env.reset(seed=3)
    policy = load_policy(run_dir, env)
    again = load_policy(run_dir / run["latest_checkpoint"], env)
    actions = policy.act(obs)
    assert actions.shape == (1, 7) and np.all(np.abs(actions) <= 1)
    np.testing.assert_array_equal(actions, again.act(obs))
    from wirecraft.rl import policy_env_kwargs

    assert policy_env_kwargs(run_dir) == {
        "control": "cartesian",
        "obs_mode": "state_rgb",
        "image_size": 24,
    }
    with pytest.raises(ValueError, match="24x24"):
        policy.act({**obs, "rgb_side": np.zeros((32, 32, 3), np.uint8)})

    train("vision-ppo", "insertion", None, run_dir, steps=16, resume=True, progress=False)
    assert json.loads((run_dir / RUN_FILE).read_text())["iterations_done"] == 2


@pytest.mark.slow
def test_vision_ppo_records_its_dagger_waves(tmp_path):
    """Two DAgger waves of one 6-step episode in each of 3 environments after the teacher's 24
    transitions: the record keeps each wave's share of teacher steps and the labels so far."""
    teacher = str(Path(__file__).parents[1] / "checkpoints" / "ppo_insertion_ethernet_seed1")
    run_dir = tmp_path / "vision"
    settings = {
        **VISION_TINY,
        "bc_epochs": 2,
        "teacher": teacher,
        "bc_dagger_waves": 2,
        "bc_dagger_envs": 3,
    }
    env_kwargs = {**SHORT, "connector": "ethernet", "image_size": 24}
    train("vision-ppo", "insertion", env_kwargs, run_dir, 8, overrides=settings, progress=False)
    bc = json.loads((run_dir / RUN_FILE).read_text())["behaviour_cloning"]
    assert bc["teacher"] == teacher
    assert [w["beta"] for w in bc["dagger_waves"]] == [0.5, 0.0]
    assert [w["transitions"] for w in bc["dagger_waves"]] == [24 + 18, 24 + 36]
    assert bc["transitions"] == 60
    assert len(bc["epoch_losses"]) == 3 * 2
    assert all(math.isfinite(v) for v in bc["epoch_losses"])


def test_vision_encoder_pools_each_camera_into_its_queries():
    import torch

    from wirecraft.rl.vision import VisualEncoder

    cfg = VisionPPOConfig(queries_per_camera=3, token_dim=8, attention_heads=2)
    encoder = VisualEncoder(cfg, image_size=32, proprio_dim=14)
    obs = {
        "rgb_side": torch.zeros(5, 32, 32, 3, dtype=torch.uint8),
        "rgb_wrist": torch.full((5, 32, 32, 3), 255, dtype=torch.uint8),
        "proprio": torch.zeros(5, 14),
    }
    features = encoder(obs)
    assert features.shape == (5, encoder.out_dim) == (5, 2 * 3 * 8 + 14)
    side, wrist = features[:, :24], features[:, 24:48]
    assert not torch.allclose(side, wrist)  # different images, different features


@pytest.mark.skipif(importlib.util.find_spec("timm") is not None, reason="timm is installed")
def test_timm_backbone_without_timm_is_a_clear_error():
    from wirecraft.rl.vision import VisualEncoder

    cfg = VisionPPOConfig(backbone="timm:vit_small_patch14_dinov2", backbone_weights="w.pt")
    with pytest.raises(ValueError, match="timm"):
        VisualEncoder(cfg, image_size=224, proprio_dim=14)


def test_load_policy_rejects_paths_outside_a_run(tmp_path):
    with pytest.raises(ValueError, match="no such"):
        load_policy(tmp_path / "missing")
    with pytest.raises(ValueError, match=RUN_FILE):
        load_policy(tmp_path)


def test_train_cli_rejects_an_existing_run_without_resume(tmp_path, capsys):
    from wirecraft.cli import main

    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "notes.txt").write_text("x")
    code = main(["train", "ppo", "--out", str(tmp_path / "run"), "--steps", "10"])
    assert code == 2 and "not an RL run directory" in capsys.readouterr().err
    code = main(["train", "ppo", "--out", str(tmp_path / "new"), "--steps", "1.5"])
    assert code == 2
    # the physics backend: PPO's only, and a Warp device only with the Warp backend
    code = main(["train", "sacfd", "--backend", "warp", "--out", str(tmp_path / "new")])
    assert code == 2 and "--backend is for ppo and vision-ppo" in capsys.readouterr().err
    code = main(["train", "ppo", "--warp-device", "cuda:0", "--out", str(tmp_path / "new")])
    assert code == 2 and "warp_device is for backend='warp'" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


@pytest.mark.slow
def test_interrupted_ppo_run_saves_its_last_complete_iteration(tmp_path, monkeypatch):
    from wirecraft.rl import ppo

    make_adapter = ppo.make_vec_env_adapter

    def interrupting_adapter(*args, **kwargs):
        env = make_adapter(*args, **kwargs)
        step = env.step

        def step_then_interrupt(actions):
            if env.env_steps >= 20 * env.num_envs:  # in iteration 2 (8 steps per iteration)
                raise KeyboardInterrupt
            return step(actions)

        env.step = step_then_interrupt
        return env

    monkeypatch.setattr(ppo, "make_vec_env_adapter", interrupting_adapter)
    settings = {**PPO_TINY, "num_envs": 2}
    with pytest.raises(KeyboardInterrupt):
        train("ppo", "insertion", SHORT, tmp_path / "run", 160, overrides=settings, progress=False)
    run = json.loads((tmp_path / "run" / RUN_FILE).read_text())
    assert run["latest_checkpoint"] == "checkpoints/model_1.pt"
    assert run["iterations_done"] == 2 and run["env_steps"] == 32
    rows = ProgressTable(tmp_path / "run" / "progress.csv").rows()
    assert [r["iteration"] for r in rows] == [0, 1]


def test_an_exported_policy_acts_as_its_run_and_cannot_be_resumed(tmp_path):
    """``python -m wirecraft.rl.export``: the actor alone and the run's record, read by
    ``load_policy`` as the run itself; resuming it is refused."""
    from wirecraft.rl.export import main as export_main

    run_dir = tmp_path / "ppo"
    train("ppo", "insertion", SHORT, run_dir, 48, overrides=PPO_TINY, progress=False)
    evaluation = tmp_path / "eval.json"
    evaluation.write_text(
        json.dumps(
            {
                "variant": "insertion",
                "protocol": {"seeds": 1, "episodes_per_seed": 2, "held_out_seed": None},
                "metrics": {"insert_success": {"mean": 0.5, "std": 0.0, "per_seed": [0.5]}},
            }
        )
    )
    out = tmp_path / "shipped"
    argv = [str(run_dir), "--out", str(out), "--command", "wirecraft train ppo ..."]
    assert export_main([*argv, "--evaluation", str(evaluation)]) == 0
    record = json.loads((out / RUN_FILE).read_text())
    assert record["checkpoints"] == [record["latest_checkpoint"]] == ["checkpoints/model_1.pt"]
    shipped = record["shipped"]
    assert shipped["train_command"] == "wirecraft train ppo ..." and shipped["from_run"]
    assert shipped["evaluations"][0]["insert_success"]["mean"] == 0.5
    full = (run_dir / "checkpoints/model_1.pt").stat().st_size
    assert (out / "checkpoints/model_1.pt").stat().st_size < full / 3
    assert (out / "progress.csv").read_text() == (run_dir / "progress.csv").read_text()
    venv = wirecraft.make_vec("insertion", 2, threads=1, **SHORT)
    obs, _ = venv.reset(seed=1)
    np.testing.assert_array_equal(
        load_policy(out, venv).act(obs), load_policy(run_dir, venv).act(obs)
    )
    with pytest.raises(ValueError, match="shipped policy"):
        train("ppo", "insertion", SHORT, out, 96, progress=False, resume=True)
    assert export_main([*argv]) == 2  # the folder exists
    assert export_main([str(run_dir), "--out", str(tmp_path / "x"), "--checkpoint", "no.pt"]) == 2
    assert not (tmp_path / "x").exists()
