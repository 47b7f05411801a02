"""DAgger on connector insertion: can a state policy imitate the scripted expert closed loop?

    python research/dagger_insertion.py --out DIR [--iterations 8] [--connector ethernet]
        [--num-envs 64] [--eval-envs 32] [--hidden 256,256] [--epochs 15] [--threads 2]
        [--expert scripted|reactive] [--expert-gain G] [--features state|relative]

Plain behaviour cloning of the insertion expert (docs/baselines.md) fits its actions well and
fails closed loop: the clone leaves the states the expert visits and never comes back.  DAgger
(Ross et al., 2011) labels the learner's own states instead.  Each iteration runs one
``--num-envs`` x 480-step wave in which every environment executes, step by step, the expert's
action with probability beta = 0.5 ** iteration (1 at iteration 0), else the learner's; the
expert, running alongside, labels every state; the learner (an MLP on the 42-d state, ELU,
MSE on all 7 action dimensions, ``--near-weight`` on labels with the plug tip within 4 cm of
home, where 3 mm of clearance asks for millimetre actions) is then trained on all labels so
far (warm start) and run deterministically in ``--eval-envs`` fresh environments (reset seed
999) for one episode.

The expert is stateful (phases, timers, poses frozen at phase changes), so a state the learner
reached can carry stale expert memory.  For labelling it runs with diversity off and
unlimited retries, and ``refresh_expert`` keeps its goals a function of the current state: the
grasp is planned again on every approach and descend step (and once at the start of close),
the lift rises from where the TCP is, an expert that finished while the plug is not seated,
or is carrying while the pads hold nothing, starts over.

``--expert reactive`` labels with ``wirecraft.experts.reactive.ReactiveInsertionExpert``
instead, whose action is a function of the state alone (nothing to refresh; ``--expert-gain``
sets its gain).  ``--features relative`` gives the learner goal-relative inputs computed from
the state as well (``ReactiveInsertionExpert.relative_features``).

Prints one JSON line per iteration (``collect``: the mixed wave's reach / insert rate at some
step and mean steps with both pads on the plug; ``eval``: the learner's alone; ``fit_mse``) and
keeps ``learner_<iteration>.pt`` and ``data.npz`` (states, labels, the expert's phase) in
``--out``.  A probe, not a baseline: it needs the expert at training time.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

import wirecraft
from wirecraft.experts.insertion import InsertionExpert, InsertionExpertConfig
from wirecraft.experts.reactive import ReactiveInsertionExpert, StateLayout
from wirecraft.rl.features import actor_input_dim

EXPERT_SEED, COLLECT_SEED, EVAL_SEED = 7, 1000, 999
STATE = StateLayout(6)  # the UR5's 42-d insertion state: its columns
NEAR_SOCKET = 0.04  # m: labels with the tip this close to home get --near-weight
CARRYING = ("pre_insert", "insert", "back_out")
FINISHED = ("release", "withdraw", "retreat", "done")
FEATURES = {
    "state": lambda states: states,
    "relative": ReactiveInsertionExpert.relative_features,
}  # learner inputs


class Learner:
    """An MLP from the standardised state to the 7-d action, fitted by MSE."""

    def __init__(
        self, hidden: tuple[int, ...], features: str = "state", action_dim: int = 7
    ) -> None:
        self.features = features
        self.transform = FEATURES[features]
        obs_dim = actor_input_dim(features, STATE.size)
        layers, width = [], obs_dim
        for h in hidden:
            layers += [torch.nn.Linear(width, h), torch.nn.ELU()]
            width = h
        self.net = torch.nn.Sequential(*layers, torch.nn.Linear(width, action_dim))
        self.hidden = hidden
        self.mean = torch.zeros(obs_dim)
        self.std = torch.ones(obs_dim)

    def fit(
        self, obs: np.ndarray, actions: np.ndarray, epochs: int, near_weight: float = 1.0
    ) -> float:
        """Weighted MSE; returns the last epoch's mean (unweighted) squared error."""
        x = torch.tensor(self.transform(obs), dtype=torch.float32)
        y = torch.tensor(actions, dtype=torch.float32)
        near = np.linalg.norm(obs[:, STATE.tip_to_target], axis=1) < NEAR_SOCKET
        weight = torch.tensor(np.where(near, near_weight, 1.0), dtype=torch.float32)[:, None]
        self.mean, self.std = x.mean(0), x.std(0) + 1e-6
        x = (x - self.mean) / self.std
        optimizer = torch.optim.Adam(self.net.parameters(), 1e-3)
        total = 0.0
        for _ in range(epochs):
            total = 0.0
            for idx in torch.randperm(len(x)).split(1024):
                squared = (self.net(x[idx]) - y[idx]) ** 2
                loss = (weight[idx] * squared).sum() / (weight[idx].sum() * squared.shape[1])
                optimizer.zero_grad()
                loss.backward()
                optimizer.step()
                total += float(squared.detach().mean()) * len(idx)
        return total / len(x)

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            x = torch.tensor(self.transform(obs), dtype=torch.float32)
            x = (x - self.mean) / self.std
            return np.clip(self.net(x).numpy(), -1.0, 1.0)

    def save(self, path: Path) -> None:
        state = {"net": self.net.state_dict(), "mean": self.mean, "std": self.std}
        torch.save({**state, "hidden": self.hidden, "features": self.features}, path)


def labelling_expert(venv) -> InsertionExpert:
    config = dataclasses.replace(
        InsertionExpertConfig(),
        diversity=False,  # one label per state: no pick-and-drop, random pauses or speeds
        max_grasp_retries=10**6,
        max_insert_retries=10**6,
    )
    return InsertionExpert(venv, config=config, seed=EXPERT_SEED)


def refresh_expert(expert: InsertionExpert, seated: np.ndarray) -> None:
    """Re-derive the expert's frozen goals from the current state (module docstring)."""
    fsm, snap = expert.fsm, expert.fsm.snapshots
    lost = fsm.in_phase(*FINISHED) & ~seated
    lost |= fsm.in_phase(*CARRYING) & ~np.array([bool(v and v.held) for v in expert.views])
    if lost.any():
        expert.reset(np.flatnonzero(lost))
    for i in np.flatnonzero(fsm.in_phase("approach", "descend", "close", "lift")):
        view = expert.views[i] = expert.read_state(i)
        phase = fsm.phases[fsm.phase[i]].name
        if phase == "approach":
            snap["grasp_pos"][i] = np.nan  # planned again by the expert's approach step
        elif phase == "lift":
            start = snap["lift_from"][i]
            snap["lift_from"][i] = view.tcp_pos - np.dot(view.tcp_pos - start, view.up) * view.up
        elif phase == "descend" or fsm.steps[i] == 0:
            expert._take_grasp_goal(i)


def make_expert(kind: str, venv, gain: float | None = None):
    """The labelling expert: ``scripted`` (``labelling_expert``) or ``reactive`` (``gain``:
    its ``ReactiveInsertionExpert.gain``, None for the default)."""
    if kind == "scripted":
        return labelling_expert(venv)
    return ReactiveInsertionExpert(venv, gain=gain)


def run_wave(venv, expert, learner, beta: float, seed: int, rng) -> tuple:
    """One episode in every environment; returns (states, labels, phases, stats). ``learner``
    None: the expert alone; ``expert`` None: the learner alone, no labels."""
    obs, _ = venv.reset(seed=seed)
    n = venv.num_envs
    scripted = isinstance(expert, InsertionExpert)
    if scripted:
        expert.reset(seed=seed)
    states, labels, phases = [], [], []
    reach, insert, seated = np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool)
    pads = np.zeros(n)
    for _ in range(venv.envs[0].max_steps):
        if scripted:
            refresh_expert(expert, seated)
            phases.append(expert.fsm.phase.copy())  # the phase the label is made in
            label = expert.act(obs)
        elif expert is not None:
            label = expert.act(obs)
            phases.append(expert.phase.copy())  # the rule that made the label
        if expert is not None:
            states.append(obs.copy())
            labels.append(label)
        action = label if learner is None else learner(obs)
        if learner is not None and expert is not None and beta > 0:
            mixed = rng.random(n) < beta
            action[mixed] = label[mixed]
        obs, _, terminated, truncated, info = venv.step(action)
        seated = np.asarray(info["insert_success"], bool)
        reach |= np.asarray(info["reach_success"], bool)
        insert |= seated
        pads += obs[:, STATE.pads].prod(axis=1)  # both pads on the plug
        if (terminated | truncated).any():
            break
    stats = {
        "reach": float(reach.mean()),
        "insert": float(insert.mean()),
        "pads_on_plug_steps": round(float(pads.mean()), 1),
    }
    if expert is None:
        return None, None, None, stats
    return np.concatenate(states), np.concatenate(labels), np.concatenate(phases), stats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, type=Path)
    parser.add_argument("--iterations", type=int, default=8)
    parser.add_argument("--connector", default="ethernet")
    parser.add_argument("--num-envs", type=int, default=64)
    parser.add_argument("--eval-envs", type=int, default=32)
    parser.add_argument("--hidden", default="256,256", help="learner hidden layer widths")
    parser.add_argument("--epochs", type=int, default=15, help="per iteration (30 at the first)")
    parser.add_argument(
        "--near-weight",
        type=float,
        default=1.0,
        help=f"loss weight of labels with the plug tip within {NEAR_SOCKET * 100:.0f} cm of home",
    )
    parser.add_argument(
        "--expert",
        choices=("scripted", "reactive"),
        default="scripted",
        help="labeller: the scripted expert (refreshed) or ReactiveInsertionExpert (state alone)",
    )
    parser.add_argument(
        "--expert-gain",
        type=float,
        default=None,
        help="the reactive expert's gain, in (0, 1] (default: its own, 0.5)",
    )
    parser.add_argument(
        "--features",
        choices=tuple(FEATURES),
        default="state",
        help="learner inputs: the 42-d state, or it plus goal-relative ones (relative_features)",
    )
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    try:
        hidden = tuple(int(h) for h in args.hidden.split(","))
    except ValueError:
        parser.error(f"--hidden must be comma-separated widths, got {args.hidden!r}")
    if args.iterations < 1 or args.num_envs < 1 or args.eval_envs < 1 or args.epochs < 1:
        parser.error("--iterations, --num-envs, --eval-envs and --epochs must be >= 1")
    if not 0 < args.near_weight < float("inf"):
        parser.error(f"--near-weight must be a finite number > 0, got {args.near_weight}")
    if args.expert_gain is not None and (
        args.expert != "reactive" or not 0 < args.expert_gain <= 1
    ):
        parser.error(
            f"--expert-gain needs --expert reactive and a value in (0, 1], got {args.expert_gain}"
        )
    if not hidden or min(hidden) < 1:
        parser.error(f"--hidden must be positive widths, got {args.hidden!r}")

    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    options = {"threads": args.threads, "control": InsertionExpert.CONTROL}
    try:  # a bad --connector or --threads: an error before anything is written
        venv = wirecraft.make_vec("insertion", args.num_envs, connector=args.connector, **options)
    except ValueError as err:
        parser.error(str(err))
    eval_venv = wirecraft.make_vec("insertion", args.eval_envs, connector=args.connector, **options)
    args.out.mkdir(parents=True, exist_ok=True)
    expert = make_expert(args.expert, venv, args.expert_gain)
    learner = Learner(hidden, args.features)
    states, labels, phases = [], [], []
    start = time.time()
    for it in tqdm(range(args.iterations), desc="DAgger iterations"):
        beta = 0.5**it
        s, a, p, collected = run_wave(
            venv, expert, learner if it else None, beta, COLLECT_SEED + it, rng
        )
        states.append(s)
        labels.append(a)
        phases.append(p)
        fit_mse = learner.fit(
            np.concatenate(states),
            np.concatenate(labels),
            args.epochs * (2 if it == 0 else 1),
            args.near_weight,
        )
        _, _, _, evaluated = run_wave(eval_venv, None, learner, 0.0, EVAL_SEED, rng)
        row = {
            "iteration": it,
            "beta": beta,
            "collect": collected,
            "labels": int(sum(len(x) for x in labels)),
            "fit_mse": round(fit_mse, 5),
            "eval": evaluated,
            "minutes": round((time.time() - start) / 60, 1),
        }
        tqdm.write(json.dumps(row))
        learner.save(args.out / f"learner_{it}.pt")
        np.savez(
            args.out / "data.npz",
            states=np.concatenate(states),
            labels=np.concatenate(labels),
            phases=np.concatenate(phases),
        )
    venv.close()
    eval_venv.close()


if __name__ == "__main__":
    main()
