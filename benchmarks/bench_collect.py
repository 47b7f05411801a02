"""Demonstrations per hour of ``wirecraft collect`` (insertion, Ethernet, two cameras).

    python benchmarks/bench_collect.py [--episodes 12] [--workers 2] [--image-size 224]
        [--fps 30] [--json PATH]

Collects ``--episodes`` scripted insertion demonstrations into a temporary dataset exactly as
``wirecraft collect`` does (worker processes generate, this process writes), then prints the
throughput and where the CPU time goes, per saved episode:

- physics + expert: ``env.step`` and ``expert.act`` in the workers;
- rendering: both cameras, in the workers (Mesa's threads included);
- writing: this process (lerobot's ``add_frame`` / ``save_episode`` / commits), split into
  video encoding alone (the episode's frames re-encoded with the dataset's own encoder
  settings, measured separately) and the rest (lerobot's per-frame image statistics in the
  encoder threads, parquet, metadata).

The figures are CPU seconds: wall-clock times are distorted when other jobs share the cores.
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=12)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--image-size", type=int, default=224)
    parser.add_argument("--fps", type=int, default=30)
    parser.add_argument("--vcodec", default="h264", help="h264 or libsvtav1")
    parser.add_argument("--json", metavar="PATH")
    args = parser.parse_args()

    from wirecraft.datasets.collect import CollectSettings, collect, run_episode
    from wirecraft.datasets.writer import quiet_writing

    quiet_writing()
    settings = CollectSettings(
        task="insertion",
        env_kwargs={"connector": "ethernet"},
        image_size=args.image_size,
        fps=args.fps,
        vcodec=args.vcodec,
    )
    with tempfile.TemporaryDirectory() as tmp:
        report = collect(settings, Path(tmp) / "ds", args.episodes, workers=args.workers)
    n = max(report.new_episodes, 1)
    attempts = max(report.new_attempts, 1)
    t = report.timing
    # Encoding alone, on one episode's frames (both cameras), in this process.
    sample = run_episode(settings, 0)
    encode = sum(encode_seconds(sample.images[c], args.fps, args.vcodec) for c in sample.images)
    frames = len(sample)
    per_episode = {
        "physics_expert_cpu_s": t["physics_cpu_s"] / attempts,
        "rendering_cpu_s": t["render_cpu_s"] / attempts,
        "writing_cpu_s": t["write_cpu_s"] / n,
        "encoding_only_cpu_s_per_frame": encode / frames / 2,
    }
    frames_per_episode = report.new_frames / n
    encoding = per_episode["encoding_only_cpu_s_per_frame"] * 2 * frames_per_episode
    per_episode["encoding_cpu_s"] = encoding
    per_episode["writing_other_cpu_s"] = per_episode["writing_cpu_s"] - encoding
    rate = report.new_episodes / report.seconds * 3600.0
    # Without the start-up (spawning the workers, importing lerobot, the first episode):
    steady = (report.new_episodes - 1) / (report.seconds - report.first_save_s) * 3600.0
    total_cpu = (
        per_episode["physics_expert_cpu_s"]
        + per_episode["rendering_cpu_s"]
        + per_episode["writing_cpu_s"]
    )
    print(
        f"insertion/ethernet, {args.image_size}x{args.image_size} side + wrist cameras, "
        f"{args.fps} fps, {args.vcodec}, {args.workers} workers: {report.new_episodes} episodes "
        f"({report.success_rate:.0%} success) in {report.seconds:.1f} s "
        f"= {rate:.0f} demonstrations/hour ({steady:.0f}/hour after the first episode)"
    )
    print(f"CPU seconds per saved episode ({frames_per_episode:.0f} frames): {total_cpu:.2f}")
    for key, value in per_episode.items():
        if key != "encoding_only_cpu_s_per_frame":
            print(f"  {key:24s} {value:6.2f}")
    print(f"  (encoding alone: {1000 * per_episode['encoding_only_cpu_s_per_frame']:.1f} ms/frame)")
    if args.json:
        Path(args.json).write_text(
            json.dumps(
                {
                    "demos_per_hour": rate,
                    "steady_demos_per_hour": steady,
                    "report": report.to_dict(),
                    "per_episode": per_episode,
                },
                indent=2,
            )
        )


if __name__ == "__main__":
    main()
