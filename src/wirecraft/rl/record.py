"""Rollouts of a trained RL policy recorded as a dataset in the shared schema (source ``rl``),
through ``wirecraft.datasets`` (``EpisodeRecorder`` + ``EpisodeWriter``, LeRobot v3).

The environment is the run's own (task and keywords from ``wirecraft_rl.json``); the recorder
renders the side and wrist cameras itself, so state policies record images too.  Every
episode is kept, successful or not: the success flags are in the data.
"""

from __future__ import annotations

import os
from pathlib import Path

from wirecraft.rl.common import find_run_dir, read_run


def record_rollouts(
    policy_path: str | os.PathLike,
    out: str | os.PathLike,
    episodes: int,
    *,
    seed: int = 0,
    fps: int = 30,
    image_size: int | None = None,
    episode_seconds: float | None = None,
    progress: bool = True,
    action: str = "joint",
) -> dict:
    """Run the policy of ``policy_path`` (a run directory or checkpoint) for ``episodes``
    episodes (reset seeds ``seed``, ``seed + 1``, ...) and write them to a new dataset at
    ``out`` whose ``action`` is ``action`` (``schema.ACTION_KINDS``).  Returns {"episodes"
    (written), "frames", "successes"}."""
    from tqdm import tqdm

    import wirecraft
    from wirecraft.datasets import EpisodeRecorder
    from wirecraft.datasets.writer import EpisodeWriter
    from wirecraft.rl.training import load_policy

    if isinstance(episodes, bool) or not isinstance(episodes, int) or episodes < 1:
        raise ValueError(f"episodes must be an integer >= 1, got {episodes!r}")
    run = read_run(find_run_dir(policy_path))
    env_kwargs = dict(run["env_kwargs"])
    if image_size is not None:
        if run["algorithm"] == "vision-ppo" and image_size != run["obs"]["image_size"]:
            raise ValueError(
                f"a vision policy sees {run['obs']['image_size']} px images; got {image_size}"
            )
        env_kwargs["image_size"] = image_size
    if episode_seconds is not None:
        env_kwargs["episode_seconds"] = episode_seconds
    env = wirecraft.make(run["task"], **env_kwargs)
    policy = load_policy(policy_path, env)
    recorder = EpisodeRecorder(env, fps, source="rl", action=action)
    writer = EpisodeWriter.create(
        Path(out), recorder.features(), fps, robot_type=env.unwrapped.robot_name
    )
    frames = successes = written = 0
    try:
        for k in tqdm(range(episodes), desc="rl rollouts", unit="episode", disable=not progress):
            obs, info = env.reset(seed=seed + k)
            policy.reset()
            recorder.start(info, seed + k)
            while True:
                action = policy.act(obs)[0]
                obs, _, terminated, truncated, info = env.step(action)
                recorder.record(action, info)
                if terminated or truncated:
                    break
            episode = recorder.finish({"policy": str(policy_path), "algorithm": run["algorithm"]})
            episode.success = bool(episode.success and not info["diverged"])
            if len(episode) == 0:  # diverged before the first whole frame
                continue
            writer.add_episode(episode)
            written += 1
            frames += len(episode)
            successes += int(episode.success)
    finally:
        writer.close()
        recorder.close()
        env.close()
    return {"episodes": written, "frames": frames, "successes": successes}
