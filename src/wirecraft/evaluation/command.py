"""``wirecraft eval``: the command's flags and what it does with them (cli.py stays thin)."""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

MAX_AUTO_VIDEOS = 6
# The reference protocol (kept here as literals so that ``wirecraft --help`` imports nothing
# heavy; a test checks them against seeds.py and retention.py).
REFERENCE_SEEDS = 4
REFERENCE_EPISODES = 16
DEFAULT_FORCE = 2.0  # N


def configure(p: argparse.ArgumentParser, add_task_args) -> None:
    from wirecraft.cli import MAX_ENVS, MAX_SECONDS, MAX_SEED, MAX_WORKERS
    from wirecraft.cli_args import (
        add_backend_args,
        number,
        output_dir,
        output_file,
        ray_address,
        suffixed,
    )

    add_task_args(p)
    p.add_argument(
        "--policy",
        nargs="+",
        default=["scripted"],
        help="scripted, random, zero, an RL run directory (wirecraft_rl.json) or a LeRobot "
        "pretrained-policy directory; several: one policy trained with several seeds, each "
        "evaluated on the same seeds, reported as mean +/- std across them",
    )
    p.add_argument(
        "--seeds",
        type=number(1, 10_000, integer=True),
        default=REFERENCE_SEEDS,
        help="evaluation seeds",
    )
    p.add_argument(
        "--episodes",
        type=number(1, 100_000, integer=True),
        default=REFERENCE_EPISODES,
        help="episodes per seed",
    )
    p.add_argument(
        "--seed",
        type=number(0, MAX_SEED, integer=True),
        default=None,
        help="evaluate on a fresh seed list derived from this number (held-out check) instead "
        "of the frozen public list",
    )
    p.add_argument(
        "--episode-seconds",
        type=number(0, MAX_SECONDS, low_open=True),
        default=None,
        help="episode length (s); default: the task's (8 s; routing 8 s per clip)",
    )
    p.add_argument(
        "--episode-steps",
        type=number(1, MAX_SECONDS * 60, integer=True),
        default=None,
        help="episode length in control steps (60 per second), instead of --episode-seconds "
        "(the reference evaluates imitation policies over 800)",
    )
    from wirecraft.tasks import TASKS

    pulling = ", ".join(n for n in TASKS if TASKS.get(n).metrics.pulls)
    p.add_argument(
        "--retain-force",
        type=number(0, 1000),
        default=None,
        help=f"{pulling} only: the retention check's pull on the seated part, 0 to 1000 N "
        f"(default: {DEFAULT_FORCE:g})",
    )
    where = p.add_mutually_exclusive_group()
    where.add_argument(
        "--workers", type=number(1, MAX_WORKERS, integer=True), default=1, help="worker processes"
    )
    where.add_argument(
        "--ray",
        metavar="ADDRESS",
        type=ray_address,
        help="run on a Ray cluster: HOST:PORT, auto, or local (start one here)",
    )
    p.add_argument(
        "--batch",
        type=number(1, MAX_ENVS, integer=True),
        default=None,
        help="environments stepped together",
    )
    add_backend_args(p)
    p.add_argument(
        "--json", metavar="PATH", type=output_file, help="write the results (metrics, episodes)"
    )
    p.add_argument(
        "--traces",
        metavar="PATH",
        type=suffixed(".parquet"),
        help="write per-step traces (Parquet, .parquet)",
    )
    p.add_argument(
        "--video", metavar="DIR", type=output_dir, help="write MP4 videos of chosen episodes"
    )
    p.add_argument(
        "--video-episodes",
        default=None,
        help="with --video or --report: auto (first success + first of each failure label; "
        "the default), all, or SEED:EPISODE,...",
    )
    p.add_argument(
        "--report", metavar="DIR", type=output_dir, help="add this run to the HTML report in DIR"
    )
    p.add_argument(
        "--device", default=None, help="torch device for learned policies (default: cpu)"
    )
    p.add_argument(
        "--fps",
        type=number(1, 60, integer=True),
        default=None,
        help="LeRobot policies: the frame rate of the dataset the policy was trained on, a "
        "divisor of 60 (default: read from the checkpoint's train_config.json)",
    )
    p.add_argument(
        "--torch-threads",
        type=number(0, 1024, integer=True),
        default=1,
        help="torch's threads in each process stepping a learned policy (0: torch's default; "
        "default: 1)",
    )
    p.add_argument(
        "--label",
        default=None,
        help="the run's name in the JSON and the report (default: from the policy's path, "
        "e.g. act_run/020000 for act_run/checkpoints/020000/pretrained_model)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument(
        "--checkpoints",
        default=None,
        help="sweep a training run's checkpoints: all, last, or N,M,... (an imitation run's "
        "training steps, RUN/checkpoints/NNNNNN; an RL run's checkpoint numbers, model_N.pt or "
        "agent_N.pt); one row per checkpoint (default: all). An imitation run is always swept; "
        "an RL run only with --checkpoints, --select or --curve (alone, --policy RUN is its "
        "latest checkpoint)",
    )
    p.add_argument(
        "--select",
        choices=("reference", "validation"),
        default=None,
        help="sweep and pick a checkpoint: reference = the top 3 of the last 5 checkpoints (or "
        "--checkpoints) on the evaluation seeds; validation = the best on the --seed list, "
        "scored on the public list. Best: by SR reach for imitation runs, by success for RL "
        "runs. With several --policy runs, each is swept and its pick enters the "
        "mean +/- std across runs",
    )
    p.add_argument(
        "--curve",
        metavar="PNG",
        type=suffixed(".png"),
        default=None,
        help="with one --policy RUN: plot the sweep's learning curve (SR reach / insert against "
        "the checkpoints' training steps or iterations)",
    )


def parse_video_spec(spec: str) -> str | list[tuple[int, int]]:
    """``auto``, ``all`` or a list of (seed, episode) from ``--video-episodes``."""
    if spec in ("auto", "all"):
        return spec
    wanted = []
    for item in spec.split(","):
        try:
            seed, episode = (int(v) for v in item.split(":"))
        except ValueError:
            raise ValueError(
                f"--video-episodes: expected auto, all or SEED:EPISODE,..., got {spec!r}"
            ) from None
        wanted.append((seed, episode))
    return wanted


def choose_videos(results, spec: str) -> list:
    """The ``EpisodeResult``s to film for ``--video-episodes``."""
    wanted = parse_video_spec(spec)
    if wanted == "all":
        return list(results)
    if wanted == "auto":
        chosen, seen = [], set()
        for r in results:
            key = "success" if r.summary["success"] else r.summary["failure"]
            if key not in seen:
                seen.add(key)
                chosen.append(r)
        return chosen[:MAX_AUTO_VIDEOS]
    by_key = {(r.spec.seed_index, r.spec.episode): r for r in results}
    missing = [w for w in wanted if w not in by_key]
    if missing:
        raise ValueError(f"--video-episodes: no such episodes {missing} in this evaluation")
    return [by_key[w] for w in wanted]


def print_summary(payload: dict, seconds: float) -> None:
    proto = payload["protocol"]
    which = (
        f"held-out list --seed {proto['held_out_seed']}"
        if proto["held_out_seed"] is not None
        else f"public seeds {proto['version']}"
    )
    print(
        f"{payload['variant']} · policy {payload.get('label') or payload['policy']} · "
        f"{proto['seeds']} seeds x "
        f"{proto['episodes_per_seed']} episodes x {proto['episode_steps']} steps ({which})"
    )
    for name, value in payload["metrics"].items():
        per_seed = ", ".join("-" if v is None else f"{100 * v:.0f}" for v in value["per_seed"])
        print(
            f"  {name:15s} {100 * value['mean']:5.1f} +/- {100 * value['std']:4.1f} %"
            f"   (per seed: {per_seed})"
        )
    failures = ", ".join(f"{k} {v}" for k, v in payload["failures"].items()) or "none"
    print(f"  failures: {failures}")
    print(f"  ({seconds:.0f} s)")


def check_policy(args, policy: str) -> None:
    """Usage errors for ``policy`` (one of ``--policy``'s values) and the flags that depend on
    what it is."""
    from wirecraft.cli import only_with, usage_error
    from wirecraft.evaluation.policies import BUILTIN_POLICIES, _lerobot_config

    if policy in BUILTIN_POLICIES:
        only_with(args, "a learned policy (an RL run or LeRobot directory)", "--device")
    elif not Path(policy).exists():
        raise usage_error(
            "--policy",
            f"{policy!r} is neither {', '.join(BUILTIN_POLICIES)} nor an existing directory",
        )
    if policy in BUILTIN_POLICIES or _lerobot_config(Path(policy)) is None:
        only_with(args, "a LeRobot policy directory", "--fps")


def print_across_runs(policies: list[str], across: dict) -> None:
    print(f"across {len(policies)} runs (mean +/- population std of each run's mean):")
    for name, value in across.items():
        if value["mean"] is None:
            continue
        per_run = ", ".join("-" if v is None else f"{100 * v:.1f}" for v in value["per_run"])
        print(
            f"  {name:15s} {100 * value['mean']:5.1f} +/- {100 * value['std']:4.1f} %"
            f"   (per run: {per_run})"
        )


SWEPT = "--policy RUN (a training run folder with checkpoints)"


def across_figure(result: dict) -> dict:
    """A swept run's figure in a comparison across runs: its selection's score (validation)
    or the mean of its top checkpoints (reference)."""
    selection = result["selection"]
    if selection["method"] == "validation":
        return {"metrics": selection["score"]["metrics"]}
    return {"metrics": selection["mean_of_top"]}


def run_across(args, family: str, env_kwargs: dict, evaluate, evaluate_sweep, write_json) -> int:
    """``--policy A B C``: each evaluated on the same seeds, then aggregated across them.  With
    ``--select``, each is a training run whose sweep picks the checkpoint that enters the
    aggregate."""
    from wirecraft.cli import only_with, usage_error
    from wirecraft.evaluation import sweep as sweep_mod
    from wirecraft.evaluation.policies import BUILTIN_POLICIES
    from wirecraft.evaluation.protocol import aggregate_runs

    policies = args.policy
    one = "one --policy"
    only_with(args, one, "--traces", "--video", "--report", "--label", "--curve")
    if args.select is None:
        only_with(args, "--select (several runs)", "--checkpoints")
    swept = {}
    for policy in policies:
        check_policy(args, policy)
        builtin = policy in BUILTIN_POLICIES
        run = None if builtin else sweep_mod.swept_run(policy, args.select is not None)
        if args.select is not None and run is None:
            raise usage_error("--select", f"{policy} is not {SWEPT}")
        if run is not None:
            sweep_mod.choose(run.checkpoints, args.checkpoints, args.select)  # a typo fails now
        if args.select is None and not builtin and sweep_mod.is_imitation_run(policy):
            raise usage_error(
                "--policy",
                f"{policy} is an imitation run (a checkpoint sweep); give checkpoints, or "
                "--select to pick one in each run",
            )
        swept[policy] = run
    if len(set(policies)) != len(policies):
        raise usage_error("--policy", f"a policy is given twice: {policies}")
    start = time.time()
    runs, figures = [], []
    for policy in policies:
        if swept[policy] is None:
            payload = evaluate(policy)
            print_summary(payload, time.time() - start)
            runs.append(payload)
            figures.append(payload)
        else:
            result = evaluate_sweep(policy, swept[policy])
            print(f"{policy}:")
            sweep_mod.print_sweep(result)
            runs.append(result)
            figures.append(across_figure(result))
    across = aggregate_runs(figures)
    print_across_runs(policies, across)
    write_json(
        args.json,
        {
            "task": family,
            "env_kwargs": env_kwargs,
            "policies": list(policies),
            "select": args.select,
            "across_runs": across,
            "runs": runs,
        },
    )
    return 0


def run(args, task_kwargs, write_json) -> int:
    from wirecraft.cli import only_with, usage_error
    from wirecraft.envs.env import CONTROL_HZ, steps_per_frame
    from wirecraft.evaluation import report as report_mod
    from wirecraft.evaluation import sweep as sweep_mod
    from wirecraft.evaluation.policies import BUILTIN_POLICIES as BUILT_IN_POLICIES
    from wirecraft.evaluation.protocol import run_evaluation
    from wirecraft.evaluation.traces import write_traces
    from wirecraft.tasks import TASKS

    family, env_kwargs = task_kwargs(args)
    if args.backend == "warp":
        env_kwargs.update(backend="warp", device=args.warp_device)
    else:
        only_with(args, "--backend warp", "--warp-device")
    policies = args.policy
    args.policy = policies[0]
    sweep_flags = any(v is not None for v in (args.checkpoints, args.select, args.curve))
    swept = None
    if len(policies) == 1 and args.policy not in BUILT_IN_POLICIES:
        swept = sweep_mod.swept_run(args.policy, sweep_flags)
    if len(policies) == 1 and swept is None:
        only_with(args, SWEPT, "--checkpoints", "--select", "--curve")
    elif swept is not None:
        only_with(
            args, "one checkpoint (not a sweep)", "--traces", "--video", "--report", "--label"
        )
    if args.select == "validation" and args.seed is None:  # one run or several
        raise usage_error("--seed", "--select validation picks on the --seed N list: pass it")
    if not TASKS.get(family).metrics.pulls:
        pulling = ", ".join(n for n in TASKS if TASKS.get(n).metrics.pulls)
        only_with(
            args, f"--task {pulling} (the families whose retention check pulls)", "--retain-force"
        )
    if not (args.video or args.report):
        only_with(args, "--video or --report", "--video-episodes")
    episode_seconds = args.episode_seconds
    if args.episode_steps is not None:
        only_with(args, "no --episode-steps (give one length)", "--episode-seconds")
        episode_seconds = args.episode_steps / CONTROL_HZ
    check_policy(args, args.policy)
    if args.fps is not None:
        try:
            steps_per_frame(args.fps)
        except ValueError as err:
            raise usage_error("--fps", str(err)) from None
    if args.label is not None and not args.label.strip():
        raise usage_error("--label", "must not be empty")
    retain_force = DEFAULT_FORCE if args.retain_force is None else args.retain_force
    args.video_episodes = args.video_episodes or "auto"
    device = args.device or "cpu"
    wanted = parse_video_spec(args.video_episodes)  # a typo fails now, not after the run
    if isinstance(wanted, list):
        outside = [w for w in wanted if not (0 <= w[0] < args.seeds and 0 <= w[1] < args.episodes)]
        if outside:
            raise ValueError(f"--video-episodes: no such episodes {outside} in this evaluation")
    policy_kwargs = {"device": device} if device != "cpu" else {}
    if args.fps is not None:
        policy_kwargs["fps"] = args.fps

    def evaluation_of(policy, seed=args.seed, label=None):
        return run_evaluation(
            family,
            str(policy),
            seeds=args.seeds,
            episodes=args.episodes,
            workers=args.workers,
            seed=seed,
            episode_seconds=episode_seconds,
            retain_force=retain_force,
            batch=args.batch,
            ray_address=args.ray,
            progress=not args.quiet,
            policy_kwargs=policy_kwargs or None,
            torch_threads=args.torch_threads,
            label=label,
            **env_kwargs,
        )

    def evaluate_sweep(policy, run):
        checkpoints = sweep_mod.choose(run.checkpoints, args.checkpoints, args.select)

        def evaluate(path, held_out):
            return evaluation_of(path, held_out).payload

        result = sweep_mod.sweep(evaluate, checkpoints, args.select, args.seed, run.rank_by)
        result.update(
            policy=str(policy),
            task=family,
            env_kwargs=env_kwargs,
            seeds=args.seeds,
            episodes_per_seed=args.episodes,
            step_unit=run.unit,
        )
        return result

    if len(policies) > 1:
        args.policy = policies
        return run_across(
            args,
            family,
            env_kwargs,
            lambda policy: evaluation_of(policy).payload,
            evaluate_sweep,
            write_json,
        )
    start = time.time()
    if swept is not None:
        result = evaluate_sweep(args.policy, swept)
        sweep_mod.print_sweep(result)
        if args.curve:
            print(f"wrote {sweep_mod.plot_curve(result, args.curve)}")
        print(f"  ({time.time() - start:.0f} s)")
        write_json(args.json, result)
        return 0
    evaluation = evaluation_of(args.policy, label=args.label)
    payload = evaluation.payload
    print_summary(payload, time.time() - start)
    write_json(args.json, payload)
    if args.traces:
        from wirecraft.cli_args import atomic_path

        with atomic_path(args.traces) as tmp:
            write_traces(tmp, family, evaluation.results)
        print(f"wrote {args.traces}")
    videos: dict[str, Path] = {}
    if args.video or args.report:
        from wirecraft.evaluation.video import record_episode

        slug = report_mod.run_slug(payload)
        folder = Path(args.video) if args.video else Path(args.report) / "videos" / slug
        for result in choose_videos(evaluation.results, args.video_episodes):
            spec, summary = result.spec, result.summary
            outcome = "success" if summary["success"] else summary["failure"]
            path = folder / f"seed{spec.seed_index}_ep{spec.episode}_{outcome}.mp4"
            replay = record_episode(evaluation.config, spec, summary, path)
            if not replay["matches"]:
                print(f"warning: the replay of {path.name} did not reproduce its outcome")
            videos[f"seed {spec.seed_index}, episode {spec.episode}: {outcome}"] = path
        if videos:
            print(f"wrote {len(videos)} videos to {folder}")
    if args.report:
        folder = Path(args.report)
        slug = report_mod.run_slug(payload)
        in_report = {}
        for caption, path in videos.items():
            target = folder / "videos" / slug / path.name
            if path.resolve() != target.resolve():
                target.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(path, target)
            in_report[caption] = target
        report_mod.add_run(folder, evaluation, in_report)
        print(f"wrote {report_mod.build(folder)}")
    return 0
