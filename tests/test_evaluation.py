"""The evaluation protocol: frozen seeds, reproducible results, metrics, policies, the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

import wirecraft
from wirecraft import cli, golden
from wirecraft.evaluation import command, protocol, retention, seeds
from wirecraft.evaluation.policies import (
    RandomPolicy,
    ScriptedPolicy,
    load_policy,
    policy_env_kwargs,
)


# -- seeds -----------------------------------------------------------------------------------------
def test_frozen_seed_file_matches_its_documented_derivation():
    frozen = seeds.frozen_lists()
    assert len(frozen) == len(seeds.standard_variants())
    for task, kwargs in seeds.standard_variants():
        key = seeds.variant_key(task, kwargs)
        lists = frozen[key]
        assert len(lists) == seeds.REFERENCE_SEEDS
        for s, row in enumerate(lists):
            assert row == [seeds.derive_seed(key, s, e) for e in range(seeds.REFERENCE_EPISODES)]


def test_public_lists_come_from_the_file_and_extend_by_the_derivation():
    key = seeds.variant_key("insertion", {"connector": "ethernet"})
    assert key == "insertion/clearance=0.003/connector=ethernet"
    lists = seeds.episode_seeds("insertion", {}, num_seeds=5, episodes=17)
    assert np.shape(lists) == (5, 17)
    assert [row[:16] for row in lists[:4]] == seeds.frozen_lists()[key]
    assert lists[4][3] == seeds.derive_seed(key, 4, 3)
    assert len({s for row in lists for s in row}) == 5 * 17  # no repeats


def test_robot_wire_and_control_see_the_same_layouts_variants_do_not():
    base = seeds.episode_seeds("insertion", {"connector": "ethernet"}, 1, 4)
    assert seeds.episode_seeds("insertion", {"robot": "panda", "wire": "rod"}, 1, 4) == base
    assert seeds.episode_seeds("insertion", {"connector": "usb_a"}, 1, 4) != base
    assert seeds.episode_seeds("insertion", {"clearance": 0.001}, 1, 4) != base
    # An int clearance is the same variant as the float.
    assert seeds.variant_key("insertion", {"clearance": 0}) == seeds.variant_key(
        "insertion", {"clearance": 0.0}
    )


def test_held_out_lists_are_fresh_per_number():
    public = {s for row in seeds.episode_seeds("routing", {}, 4, 16) for s in row}
    held = seeds.episode_seeds("routing", {}, 4, 16, held_out=7)
    assert held == seeds.episode_seeds("routing", {}, 4, 16, held_out=7)
    assert held != seeds.episode_seeds("routing", {}, 4, 16, held_out=8)
    assert not public & {s for row in held for s in row}


def test_bad_protocol_sizes_are_rejected():
    with pytest.raises(ValueError, match="seeds and episodes"):
        seeds.episode_seeds("insertion", {}, 0, 16)
    with pytest.raises(ValueError, match="episodes must be an integer"):
        protocol.run_evaluation("insertion", "zero", episodes=0)
    with pytest.raises(ValueError, match="unknown task"):
        protocol.run_evaluation("stacking", "zero")
    with pytest.raises(ValueError, match="retain_force"):
        protocol.run_evaluation("insertion", "zero", retain_force=-1.0)


def test_cli_defaults_match_the_protocol_constants():
    assert command.REFERENCE_SEEDS == seeds.REFERENCE_SEEDS
    assert command.REFERENCE_EPISODES == seeds.REFERENCE_EPISODES
    assert command.DEFAULT_FORCE == retention.DEFAULT_FORCE


# -- metrics ---------------------------------------------------------------------------------------
def test_metrics_are_rates_per_seed_then_mean_and_population_std():
    episodes = [
        {"seed": s, "success": ok, "retain_success": False, "success_at_end": ok}
        for s, outcomes in enumerate([[1, 1, 0, 0], [1, 1, 1, 1], [0, 0, 0, 1]])
        for ok in outcomes
    ]
    metrics = protocol.aggregate("routing", episodes, 3)
    assert metrics["success"]["per_seed"] == [0.5, 1.0, 0.25]
    rates = np.array([0.5, 1.0, 0.25])
    assert metrics["success"]["mean"] == pytest.approx(rates.mean())
    assert metrics["success"]["std"] == pytest.approx(np.sqrt(np.mean((rates - rates.mean()) ** 2)))
    assert metrics["retain_success"] == {"mean": 0.0, "std": 0.0, "per_seed": [0.0, 0.0, 0.0]}


# -- reproducibility -------------------------------------------------------------------------------
def _scripted(**kw):
    return protocol.evaluate(
        "insertion", "scripted", seeds=1, episodes=2, episode_seconds=6.0, progress=False, **kw
    )


@pytest.mark.slow
def test_scripted_evaluation_reproduces_its_json_across_runs_and_worker_counts():
    def episodes_part(payload) -> str:  # provenance names the worker count
        return json.dumps({k: v for k, v in payload.items() if k != "provenance"}, sort_keys=True)

    first = episodes_part(_scripted())
    payload = json.loads(first)
    assert set(payload["metrics"]) >= {
        "success",
        "reach_success",
        "insert_success",
        "retain_success",
    }
    assert [(e["seed"], e["episode"]) for e in payload["episodes"]] == [(0, 0), (0, 1)]
    assert payload["protocol"]["reset_seeds"] == seeds.episode_seeds("insertion", {}, 1, 2)
    for episode in payload["episodes"]:
        assert episode["steps"] == 360
        assert (episode["failure"] is None) == episode["success"]
    assert episodes_part(_scripted()) == first
    # Two worker processes, one episode each (batch 1 instead of 2): the same document.
    assert episodes_part(_scripted(workers=2)) == first


def test_an_episode_does_not_depend_on_its_slot_in_a_batch():
    """The same reset seed in slot 0 of a batch of 1 and in slot 1 of a batch of 2 gives the
    same trace (random policy: its generator is seeded from the episode)."""
    config = protocol.EvalConfig("insertion", "random", {}, horizon=20, batch=2)
    alone = protocol.EvalConfig("insertion", "random", {}, horizon=20, batch=1)
    a, b = protocol.EpisodeSpec(0, 0, 11), protocol.EpisodeSpec(0, 1, 22)
    pair = protocol.run_chunk(config, [a, b])
    single = protocol.run_chunk(alone, [b])
    assert np.array_equal(pair[1].trace["insertion_depth"], single[0].trace["insertion_depth"])
    assert not np.array_equal(pair[0].trace["insertion_depth"], pair[1].trace["insertion_depth"])


# -- policies --------------------------------------------------------------------------------------
def test_builtin_policies_act_on_batches_with_the_env_action_shape():
    venv = wirecraft.make_vec("insertion", 2, threads=1)
    obs, _ = venv.reset(seed=[3, 4])
    for spec in ("zero", "random", "scripted"):
        policy = load_policy(spec, venv)
        policy.reset()
        actions = policy.act(obs)
        assert actions.shape == (2, 7) and np.all(np.abs(actions) <= 1.0)
    assert isinstance(load_policy("scripted", venv), ScriptedPolicy)
    assert load_policy("scripted", venv).phase_names() == ["approach", "approach"]
    venv.close()


def test_random_policy_actions_follow_the_episode_seed():
    venv = wirecraft.make_vec("insertion", 2, threads=1)
    venv.reset(seed=[5, 5])
    policy = RandomPolicy(venv)
    actions = policy.act(None)
    assert np.array_equal(actions[0], actions[1])  # same episode seed, same actions
    venv.reset(seed=[5, 6])
    policy.reset()
    actions = policy.act(None)
    assert not np.array_equal(actions[0], actions[1])
    venv.close()


def test_policy_specs_declare_what_the_environment_needs():
    assert policy_env_kwargs("scripted", "insertion") == {"control": "cartesian"}
    assert policy_env_kwargs("scripted", "seating") == {"control": "cartesian"}
    assert policy_env_kwargs("zero", "routing") == {}
    with pytest.raises(ValueError, match="needs control='cartesian'"):
        protocol.resolve_env_kwargs("insertion", "scripted", {"control": "joint"})
    with pytest.raises(ValueError, match="unknown policy 'nonsense'"):
        policy_env_kwargs("nonsense", "insertion")


def test_an_rl_run_directory_goes_to_wirecraft_rl(tmp_path, monkeypatch):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "wirecraft_rl.json").write_text(json.dumps({"env_kwargs": {"control": "joint"}}))
    checkpoint = run / "checkpoints" / "model_100.pt"
    checkpoint.write_bytes(b"")
    calls = []

    class FakeRL:
        @staticmethod
        def load_policy(path, env, **kw):
            calls.append((path, env))
            return "loaded"

        @staticmethod
        def policy_env_kwargs(path):
            return json.loads((path / "wirecraft_rl.json").read_text())["env_kwargs"]

    import sys

    monkeypatch.setitem(sys.modules, "wirecraft.rl", FakeRL)
    assert policy_env_kwargs(str(checkpoint), "insertion") == {"control": "joint"}
    assert load_policy(str(checkpoint), "ENV") == "loaded"
    assert calls == [(checkpoint, "ENV")]
    monkeypatch.setitem(sys.modules, "wirecraft.rl", None)  # import fails
    with pytest.raises(RuntimeError, match="RL checkpoint"):
        load_policy(str(run), "ENV")


# -- the command -----------------------------------------------------------------------------------
def test_eval_command_writes_the_json_document(tmp_path, capsys):
    out = tmp_path / "results.json"
    code = cli.main(
        [
            "eval",
            "--task",
            "insertion",
            "--connector",
            "cuboid",
            "--policy",
            "zero",
            "--seeds",
            "2",
            "--episodes",
            "1",
            "--episode-seconds",
            "0.1",
            "--json",
            str(out),
            "--quiet",
        ]
    )
    assert code == 0
    payload = json.loads(out.read_text())
    assert payload["variant"] == "insertion/clearance=0.003/connector=cuboid"
    assert payload["metrics"]["success"] == {"mean": 0.0, "std": 0.0, "per_seed": [0.0, 0.0]}
    assert [e["failure"] for e in payload["episodes"]] == ["no_grasp", "no_grasp"]
    assert payload["protocol"]["reset_seeds"] == [
        row[:1] for row in seeds.frozen_lists()[payload["variant"]][:2]
    ]
    assert payload["provenance"]["threads"] == 1
    assert payload["provenance"]["benchmark_version"] == golden.load_golden()["benchmark_version"]
    assert "success" in capsys.readouterr().out


def test_eval_command_rejects_flags_of_other_tasks(capsys):
    code = cli.main(["eval", "--task", "insertion", "--num-clips", "2", "--quiet"])
    assert code == 2
    assert "--num-clips does not apply to the insertion task" in capsys.readouterr().err


def test_protocol_horizon_is_the_task_variants_episode_length():
    """Without ``episode_seconds`` the protocol runs each variant for its own episode length
    (routing: 8 s per clip), and says so in the payload."""
    payload = protocol.run_evaluation(
        "routing", "zero", seeds=1, episodes=1, num_clips=2, progress=False
    ).payload
    assert payload["protocol"]["episode_steps"] == 2 * 480
    assert payload["episodes"][0]["steps"] == 2 * 480


def test_episode_steps_sets_the_horizon_in_control_steps(tmp_path):
    from wirecraft.cli import main

    out = tmp_path / "run.json"
    argv = ["eval", "--policy", "zero", "--seeds", "1", "--episodes", "1", "--quiet"]
    assert main([*argv, "--episode-steps", "90", "--json", str(out)]) == 0
    payload = json.loads(out.read_text())
    assert payload["protocol"]["episode_steps"] == 90
    assert payload["episodes"][0]["steps"] == 90


def test_several_policies_are_reported_across_runs(tmp_path, capsys):
    """``--policy A B``: each run is the single evaluation of that policy on the same seeds,
    and the across-runs line is the mean and population std of the runs' means."""
    common = ["eval", "--task", "insertion", "--seeds", "2", "--episodes", "1", "--quiet"]
    out = tmp_path / "across.json"
    assert cli.main([*common, "--policy", "zero", "scripted", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    singles = []
    for policy in ("zero", "scripted"):
        path = tmp_path / f"{policy}.json"
        assert cli.main([*common, "--policy", policy, "--json", str(path)]) == 0
        singles.append(json.loads(path.read_text()))
    assert doc["policies"] == ["zero", "scripted"]
    for run, single in zip(doc["runs"], singles, strict=True):
        assert run["metrics"] == single["metrics"]
        assert run["episodes"] == single["episodes"]
    for name, value in doc["across_runs"].items():
        means = [single["metrics"][name]["mean"] for single in singles]
        assert value["per_run"] == means
        assert value["mean"] == pytest.approx(np.mean(means))
        assert value["std"] == pytest.approx(np.std(means))
    assert doc["across_runs"]["success"]["per_run"] == [0.0, 1.0]  # zero never inserts
    assert "across 2 runs" in capsys.readouterr().out


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--policy", "zero", "zero"], "given twice"),
        (["--policy", "zero", "scripted", "--label", "x"], "--label"),
        (["--policy", "zero", "no/such/run"], "neither"),
    ],
)
def test_several_policies_refuse_what_applies_to_one(extra, message, capsys):
    assert cli.main(["eval", "--task", "insertion", *extra]) == 2
    assert message in capsys.readouterr().err
