"""How well a LeRobot policy fits the demonstrations it was trained on, with the states the
demonstrations visited (teacher forcing), and whether the environment shows it what the dataset
did.

    python research/il_fit.py --policy RUN/checkpoints/NNNNNN/pretrained_model --dataset DIR
        [--episodes 0,40,80] [--every 10]

For each chosen episode, the environment is reset with the episode's ``seed`` and the settings
of ``meta/wirecraft_collect.json``, and the recorded ``action.env`` are replayed in the recorded
control mode, so the states follow the demonstration.  At every ``--every``-th frame the policy
(reset, so its first action comes from a fresh chunk) predicts the frame's action twice: from
the dataset's own frame, and from the environment's observation at that frame.  Printed per
episode:

- ``state``: the largest gap between the environment's ``observation.state`` and the dataset's,
  and ``image``: the mean gap of the side camera's pixels (0-1; the dataset's video is lossy);
- ``fit``: the policy's error on the frame's joint targets (largest over the arm's joints, rad),
  median and max over the frames, from the dataset's frames and from the environment's; for a
  dataset collected with ``--action env``, on the arm part of the frame's environment actions
  (largest over them, in the actions' units: 1 = a full step's command; the gripper command
  left out, as the gripper gap is from the joint targets).

Equal ``fit`` from both sources, with small ``state`` and ``image`` gaps, says the evaluation
feeds the policy what it was trained on; then the ``fit`` itself says whether the policy has
learned its demonstrations to the precision a grasp needs.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--policy", required=True, help="a LeRobot pretrained_model folder")
    parser.add_argument("--dataset", required=True, help="the dataset it was trained on")
    parser.add_argument("--episodes", default="0", help="comma-separated episode indices")
    parser.add_argument("--every", type=int, default=10, help="frames between predictions")
    args = parser.parse_args()
    if args.every < 1:
        parser.error("--every must be >= 1")
    import torch
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    import wirecraft
    from wirecraft.datasets.writer import load_dataset
    from wirecraft.envs.env import steps_per_frame

    root = Path(args.dataset)
    settings = json.loads((root / "meta" / "wirecraft_collect.json").read_text())["settings"]
    dataset = load_dataset(root)
    config = PreTrainedConfig.from_pretrained(args.policy)
    config.device = "cpu"
    policy = get_policy_class(config.type).from_pretrained(args.policy, config=config)
    policy.eval()
    pre, post = make_pre_post_processors(
        config,
        pretrained_path=args.policy,
        preprocessor_overrides={"device_processor": {"device": "cpu"}},
    )
    env = wirecraft.make(
        settings["task"],
        obs_mode="state_rgb",
        image_size=settings["image_size"],
        **settings["env_kwargs"],
    ).unwrapped
    dof, k = env.robot.dof, steps_per_frame(settings["fps"])
    env_actions = settings.get("action", "joint") == "env"
    width = env.action_space.shape[0]
    # The arm's entries: the joints of the joint targets, or each control step's arm command.
    arm = np.arange(k * width) % width < width - 1 if env_actions else np.arange(dof + 1) < dof
    unit = "action units" if env_actions else "rad"

    def predict(state, side, wrist) -> np.ndarray:
        batch = {
            "observation.state": torch.as_tensor(state, dtype=torch.float32)[None],
            "observation.images.cam_side": side[None],
            "observation.images.cam_wrist": wrist[None],
            "task": [env.task_description],
        }
        policy.reset()
        with torch.inference_mode():
            return post(policy.select_action(pre(batch))).numpy()[0]

    def chw(image) -> torch.Tensor:
        return torch.as_tensor(np.asarray(image)).permute(2, 0, 1).float() / 255.0

    episodes = dataset.meta.episodes
    for index in (int(e) for e in args.episodes.split(",")):
        lo = int(episodes["dataset_from_index"][index])
        hi = int(episodes["dataset_to_index"][index])
        frames = [dataset[i] for i in range(lo, hi)]
        obs, _ = env.reset(seed=int(frames[0]["seed"]))
        state_gap, image_gap, fit_dataset, fit_env = [], [], [], []
        for j, frame in enumerate(frames):
            state = np.asarray(obs["proprio"])[: dof + 1]
            side, wrist = chw(obs["rgb_side"]), chw(obs["rgb_wrist"])
            state_gap.append(float(np.abs(state - frame["observation.state"].numpy()).max()))
            image_gap.append(float((side - frame["observation.images.cam_side"]).abs().mean()))
            if j % args.every == 0:
                target = frame["action"].numpy()[arm]
                recorded = predict(
                    frame["observation.state"].numpy(),
                    frame["observation.images.cam_side"],
                    frame["observation.images.cam_wrist"],
                )
                live = predict(state, side, wrist)
                fit_dataset.append(float(np.abs(recorded[arm] - target).max()))
                fit_env.append(float(np.abs(live[arm] - target).max()))
            for action in frame["action.env"].numpy().reshape(k, -1):
                obs, *_ = env.step(action)
        print(
            f"episode {index} ({len(frames)} frames): state {max(state_gap):.1e}, image "
            f"{np.mean(image_gap):.3f}; fit ({unit}) from the dataset median "
            f"{np.median(fit_dataset):.3f} max {max(fit_dataset):.3f}, from the environment "
            f"median {np.median(fit_env):.3f} max {max(fit_env):.3f}"
        )


if __name__ == "__main__":
    main()
