"""Image observations of the vector environment: frames/s and the share of a step spent drawing.

    python benchmarks/bench_render.py [--task insertion] [--num-envs 1,16] [--steps 60]
        [--image-size 224] [--json PATH]

Steps ``make_vec(task, n, obs_mode="rgb")`` (side and wrist cameras, ``--image-size`` square,
state of the batch as in training: no diagnostics) with small random actions and prints, per
``num_envs``: environment steps/s, images/s, the renderers in use (one per vector env: one
OpenGL context draws every environment), the milliseconds per image spent in
``FastRenderer.render`` (scene update, drawing, read-back) and that time's share of the step.
Rendering is on the CPU (Mesa llvmpipe, which runs its own threads): timings move when other
jobs share the cores.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def measure(task: str, num_envs: int, steps: int, image_size: int) -> dict:
    import wirecraft
    from wirecraft import render

    spent = {"seconds": 0.0, "images": 0}
    draw = render.FastRenderer.render

    def timed(self, data, camera=-1):
        tic = time.perf_counter()
        image = draw(self, data, camera)
        spent["seconds"] += time.perf_counter() - tic
        spent["images"] += 1
        return image

    render.FastRenderer.render = timed
    try:
        venv = wirecraft.make_vec(
            task, num_envs, threads=2, obs_mode="rgb", image_size=image_size, diagnostics=False
        )
        venv.reset(seed=0)
        rng = np.random.default_rng(0)
        for _ in range(3):  # warm-up: first draws upload the model
            venv.step(rng.uniform(-0.3, 0.3, venv.action_space.shape))
        spent.update(seconds=0.0, images=0)
        tic = time.perf_counter()
        for _ in range(steps):
            venv.step(rng.uniform(-0.3, 0.3, venv.action_space.shape))
        wall = time.perf_counter() - tic
        renderers = len({id(env._renderer) for env in venv.envs})
        venv.close()
    finally:
        render.FastRenderer.render = draw
    return {
        "task": task,
        "num_envs": num_envs,
        "image_size": image_size,
        "renderers": renderers,
        "env_steps_per_s": round(num_envs * steps / wall, 1),
        "images_per_s": round(spent["images"] / wall, 1),
        "ms_per_image": round(1000 * spent["seconds"] / spent["images"], 2),
        "render_share": round(spent["seconds"] / wall, 3),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--task", default="insertion")
    p.add_argument("--num-envs", default="1,16", help="comma-separated counts")
    p.add_argument("--steps", type=int, default=60, help="timed vector steps per row")
    p.add_argument("--image-size", type=int, default=224)
    p.add_argument("--json", help="write the rows as JSON")
    args = p.parse_args()
    counts = [int(n) for n in args.num_envs.split(",")]
    if args.steps < 1 or any(n < 1 for n in counts):
        p.error("--steps and --num-envs must be positive")
    rows = [measure(args.task, n, args.steps, args.image_size) for n in counts]
    header = ("envs", "renderers", "env steps/s", "images/s", "ms/image", "share")
    print(" ".join(f"{h:>{w}}" for h, w in zip(header, (5, 9, 11, 9, 8, 6), strict=True)))
    for r in rows:
        print(
            f"{r['num_envs']:>5} {r['renderers']:>9} {r['env_steps_per_s']:>11.1f} "
            f"{r['images_per_s']:>9.1f} {r['ms_per_image']:>8.2f} {r['render_share']:>6.0%}"
        )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
