"""Videos of chosen episodes, with an overlay of the policy's phase and the failure label.

Episodes are seeded, so a video replays an evaluated episode exactly: the episode is run again
alone (one environment) with rendering, side camera and wrist camera side by side, every
second control step (30 frames/s), the retention check included.  The overlay shows the
variant, seed, episode and time; the policy's phase (when it exposes one) or the retention
stage; and the outcome (success, or the failure label).  MP4 (H.264) through PyAV, text with
Pillow.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from wirecraft.envs.env import CONTROL_HZ
from wirecraft.evaluation import retention
from wirecraft.evaluation.policies import policy_phase_names
from wirecraft.mp4 import VideoWriter
from wirecraft.torch_threads import torch_threads as limit_torch_threads

FRAME_EVERY = 2  # control steps per video frame: 30 frames/s
SIDE_SIZE = (360, 270)  # width, height
WRIST_SIZE = (270, 270)


def overlay(frame: np.ndarray, lines: list[str], footer: str, footer_ok: bool | None):
    """``frame`` with ``lines`` written top-left and ``footer`` on a coloured bottom band."""
    from PIL import Image, ImageDraw, ImageFont

    image = Image.fromarray(frame)
    draw = ImageDraw.Draw(image, "RGBA")
    font = ImageFont.load_default(size=14)
    height = 18 * len(lines) + 6
    draw.rectangle([0, 0, image.width, height], fill=(0, 0, 0, 150))
    for k, line in enumerate(lines):
        draw.text((6, 3 + 18 * k), line, fill=(255, 255, 255), font=font)
    colour = {True: (20, 140, 60, 210), False: (190, 30, 30, 210), None: (60, 60, 60, 190)}
    draw.rectangle([0, image.height - 24, image.width, image.height], fill=colour[footer_ok])
    draw.text((6, image.height - 20), footer, fill=(255, 255, 255), font=font)
    return np.asarray(image)


def record_episode(config, spec, summary: dict, path: str | Path) -> dict:
    """Replay episode ``spec`` of evaluation ``config`` alone and write its video to ``path``;
    returns the replay's outcome (``success``, ``matches``: same as evaluated).  The episode's
    last frame is also saved as a PNG beside the video (its poster)."""
    from dataclasses import replace

    from wirecraft.evaluation.protocol import environment_and_policy

    single = replace(config, batch=1, threads=1)
    venv, policy = environment_and_policy(single)
    with limit_torch_threads(config.torch_threads):
        return _record(config, spec, summary, path, venv, policy)


def _record(config, spec, summary: dict, path, venv, policy) -> dict:
    from wirecraft.envs.vector import info_row
    from wirecraft.render import FastRenderer

    env = venv.envs[0]
    side_cam = env.robot.side_camera
    wrist_cam = env.robot.wrist_camera
    side = FastRenderer(env.model, SIDE_SIZE[1], SIDE_SIZE[0])
    wrist = FastRenderer(env.model, WRIST_SIZE[1], WRIST_SIZE[0])
    width = SIDE_SIZE[0] + WRIST_SIZE[0]
    writer = VideoWriter(path, width, SIDE_SIZE[1], CONTROL_HZ // FRAME_EVERY)
    label = "success" if summary["success"] else f"failure: {summary['failure']}"
    if summary.get("retain_failure") or summary.get("retain_success"):
        label += f"   retained: {summary['retain_success']}"
    title = f"{config.task}  seed {spec.seed_index}  episode {spec.episode}"
    title += f"  (reset {spec.reset_seed})"

    def frame(step: int, phase: str | None):
        image = np.concatenate(
            [side.render(env.data, side_cam), wrist.render(env.data, wrist_cam)], axis=1
        )
        lines = [title, f"t = {step / CONTROL_HZ:5.2f} s   phase: {phase or '-'}"]
        return overlay(image, lines, label, bool(summary["success"]))

    success = False
    diverged = False
    try:
        obs, _ = venv.reset(seed=[spec.reset_seed])
        policy.reset(None)
        last = frame(0, None)
        writer.add(last)
        for step in range(1, config.horizon + 1):
            actions = np.asarray(policy.act(obs), dtype=float)
            phases = policy_phase_names(policy)
            obs, _, _, _, infos = venv.step(actions)
            info = info_row(infos, 0)
            success |= bool(info["success"])
            if info["diverged"]:
                diverged = True
                break
            if step % FRAME_EVERY == 0 or step == config.horizon:
                last = frame(step, phases[0] if phases else None)
                writer.add(last)
        # The episode's last frame is the poster the report shows before playing.
        from PIL import Image

        Image.fromarray(last).save(Path(path).with_suffix(".png"))
        if not diverged and info["success"]:
            failure = None
            for k in range(retention.STEPS):
                if failure is None:
                    retention.apply_pull(env, k, config.retain_force)
                else:
                    retention.clear_pull(env)
                _, _, _, _, infos = venv.step(retention.retention_action(env, k)[None])
                failure = failure or retention.failure_at(k, bool(info_row(infos, 0)["success"]))
                if k % FRAME_EVERY == 0:
                    stage = retention.stage(k)
                    if stage.endswith("pull") and env.task.metrics.pulls:
                        stage += f" {config.retain_force:g} N"
                    writer.add(frame(config.horizon + k + 1, stage))
            retention.clear_pull(env)
    except BaseException:
        writer.discard()
        raise
    else:
        writer.close()
    finally:
        side.close()
        wrist.close()
    return {"success": success, "matches": success == bool(summary["success"])}
