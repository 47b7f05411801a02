"""Demonstrations per hour of ``wirecraft collect`` (insertion, Ethernet, two cameras).

    python benchmarks/bench_collect.py [--episodes 12] [--workers 2] [--batch 4] [--image-size 224]
        [--fps 30] [--json PATH]

Collects ``--episodes`` scripted insertion demonstrations into a temporary dataset exactly as
``wirecraft collect`` does (worker processes generate, this process writes), then prints the
throughput and where the CPU time goes, per saved episode:

- physics + expert: ``env.step`` and ``expert.act`` in the workers (failed attempts included);
- rendering: both cameras, in the workers (Mesa's threads included);
- writing: this process (lerobot's ``add_frame`` / ``save_episode`` / commits), split into
  video encoding and image statistics (each measured alone on one episode's frames, with the
  dataset's own encoder settings and ``ChannelLevelCounts``) and the rest (parquet, metadata);
- the rest, mostly once per run: this process's CPU time minus the writing (imports: ~1.3 s
  for wirecraft, ~4 s for lerobot with torch; receiving each episode's frames from a worker,
  ~0.1 s) and the workers' CPU time minus the episodes' (imports, the first scene build,
  sending the frames, and any attempt still running when the target is reached, dropped).

The figures are CPU seconds: wall-clock times are distorted when other jobs share the cores.
The CPU estimate of the throughput is ``3600 * cores / CPU seconds per episode`` with
``cores = min(workers, os.cpu_count())``, steady (the per-episode costs above only) and for
a run of ``--episodes`` (the rest included).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np


def encode_seconds(frames: np.ndarray, fps: int, vcodec: str) -> float:
    """CPU seconds to encode ``frames`` (T, H, W, 3) as the dataset's videos are encoded."""
    from fractions import Fraction

    import av
    from lerobot.configs import RGBEncoderConfig

    from wirecraft.datasets.writer import VIDEO_CODECS

    config = RGBEncoderConfig(**VIDEO_CODECS[vcodec])
    options = config.get_codec_options(encoder_threads=1, as_strings=True)
    with tempfile.TemporaryDirectory() as tmp:
        cpu = time.process_time()
        with av.open(str(Path(tmp) / "v.mp4"), "w") as container:
            stream = container.add_stream(config.vcodec, fps, options=options)
            stream.pix_fmt = config.pix_fmt
            stream.height, stream.width = frames.shape[1:3]
            stream.time_base = Fraction(1, fps)
            for i, image in enumerate(frames):
                frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="rgb24")
                frame.pts = i
                for packet in stream.encode(frame):
                    container.mux(packet)
            for packet in stream.encode():
                container.mux(packet)
        return time.process_time() - cpu


def image_stats_seconds(frames: np.ndarray) -> float:
    """CPU seconds to count one camera's frames for the image statistics, as the writer does."""
    from wirecraft.datasets.encoding import ChannelLevelCounts

    cpu = time.process_time()
    counts = ChannelLevelCounts(3)
    for image in frames:
        counts.update(image)
    counts.statistics()
    return time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=12)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--batch", type=int, default=None, help="episodes per worker side by side")
    parser.add_argument("--image-size", type=int, default=224)
    parser.add_argument("--fps", type=int, default=30)
    parser.add_argument("--vcodec", default="h264", help="h264 or libsvtav1")
    parser.add_argument("--json", metavar="PATH")
    args = parser.parse_args()

    import os
    import resource

    main_cpu0 = time.process_time()
    children0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    from wirecraft.datasets.collect import CollectSettings, collect, run_episode

    settings = CollectSettings(
        task="insertion",
        env_kwargs={"connector": "ethernet"},
        image_size=args.image_size,
        fps=args.fps,
        vcodec=args.vcodec,
    )
    with tempfile.TemporaryDirectory() as tmp:
        batch = {} if args.batch is None else {"batch": args.batch}
        report = collect(settings, Path(tmp) / "ds", args.episodes, workers=args.workers, **batch)
    main_cpu = time.process_time() - main_cpu0
    children = resource.getrusage(resource.RUSAGE_CHILDREN)  # the pool's workers, joined
    workers_cpu = (children.ru_utime - children0.ru_utime) + (
        children.ru_stime - children0.ru_stime
    )
    n = max(report.new_episodes, 1)
    t = report.timing
    # Encoding and statistics alone, on one episode's frames (both cameras), in this process.
    sample = run_episode(settings, 0)
    encode = sum(encode_seconds(sample.images[c], args.fps, args.vcodec) for c in sample.images)
    counting = sum(image_stats_seconds(sample.images[c]) for c in sample.images)
    frames_per_episode = report.new_frames / n
    scale = frames_per_episode / len(sample)
    per_episode = {
        "physics_expert_cpu_s": t["physics_cpu_s"] / n,
        "rendering_cpu_s": t["render_cpu_s"] / n,
        "writing_cpu_s": t["write_cpu_s"] / n,
        "encoding_cpu_s": encode * scale,
        "image_stats_cpu_s": counting * scale,
    }
    per_episode["writing_other_cpu_s"] = (
        per_episode["writing_cpu_s"]
        - per_episode["encoding_cpu_s"]
        - per_episode["image_stats_cpu_s"]
    )
    episode_cpu = (
        per_episode["physics_expert_cpu_s"]
        + per_episode["rendering_cpu_s"]
        + per_episode["writing_cpu_s"]
    )
    other = {
        "main_other_cpu_s": main_cpu - t["write_cpu_s"],
        "workers_other_cpu_s": workers_cpu - t["physics_cpu_s"] - t["render_cpu_s"],
    }
    cores = min(max(args.workers, 1), os.cpu_count() or 1)
    run_cpu = episode_cpu * n + sum(other.values())
    rate = report.new_episodes / report.seconds * 3600.0
    # Without the start-up (spawning the workers, importing lerobot, the first episode):
    steady = (report.new_episodes - 1) / (report.seconds - report.first_save_s) * 3600.0
    estimate = {
        "steady_demos_per_hour_from_cpu": 3600.0 * cores / episode_cpu,
        "run_demos_per_hour_from_cpu": 3600.0 * cores * n / run_cpu,
    }
    print(
        f"insertion/ethernet, {args.image_size}x{args.image_size} side + wrist cameras, "
        f"{args.fps} fps, {args.vcodec}, {args.workers} workers, "
        f"batch {args.batch or 'default'}: {report.new_episodes} episodes "
        f"({report.success_rate:.0%} success, {report.new_attempts} attempts)"
    )
    print(f"CPU seconds per saved episode ({frames_per_episode:.0f} frames): {episode_cpu:.2f}")
    for key, value in per_episode.items():
        indent = (
            "    "
            if key in ("encoding_cpu_s", "image_stats_cpu_s", "writing_other_cpu_s")
            else "  "
        )
        print(f"{indent}{key:26s} {value:6.2f}")
    print(f"CPU seconds besides (mostly start-up): {sum(other.values()):.2f}")
    for key, value in other.items():
        print(f"  {key:26s} {value:6.2f}")
    print(
        f"from CPU time, {cores} cores: {estimate['steady_demos_per_hour_from_cpu']:.0f} "
        f"demonstrations/hour steady, {estimate['run_demos_per_hour_from_cpu']:.0f}/hour for "
        f"a run of {n} (everything included)"
    )
    print(
        f"wall clock: {report.seconds:.1f} s = {rate:.0f} demonstrations/hour "
        f"({steady:.0f}/hour after the first episode; distorted when other jobs share the cores)"
    )
    if args.json:
        Path(args.json).write_text(
            json.dumps(
                {
                    "demos_per_hour": rate,
                    "steady_demos_per_hour": steady,
                    **estimate,
                    "report": report.to_dict(),
                    "per_episode": per_episode,
                    "other_cpu_s": other,
                },
                indent=2,
            )
        )


if __name__ == "__main__":
    main()
