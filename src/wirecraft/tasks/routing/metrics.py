"""What the evaluation measures for clip routing: clips routed, the held wire's distance to the
next clip, and the ``clip_missed`` failure label."""

from __future__ import annotations

import math

import numpy as np

from wirecraft.numerics import norm
from wirecraft.tasks.metrics import TaskMetrics, final, metrics_of
from wirecraft.tasks.routing.task import RoutingTask

CLIP_NEAR = 0.03  # m (horizontal), TCP to a clip: "brought to the clip"


@metrics_of(RoutingTask)
class RoutingMetrics(TaskMetrics):
    columns = (
        "clips_routed",  # count
        "clip_distance",  # m (horizontal), TCP to the nearest clip not routed (nan: none left)
    )
    failure_labels = {
        "clip_missed": (
            f"the held wire was brought within {100 * CLIP_NEAR:g} cm of a clip, which is not "
            "routed at the end"
        ),
    }
    trace_plots = (
        ("clips_routed", "clips routed", 1.0, None),
        ("fixture_force", "wire-clip force (N)", 1.0, None),
        ("wire_tension", "wire tension (N)", 1.0, None),
        ("min_bend_radius", "min bend radius (mm)", 1000.0, (0.0, 200.0)),
    )
    episode_columns = ("final_clips_routed",)

    def measure(self, env, info):
        task, model, data = env.task, env.model, env.data
        routed = task.routed(model, data)
        tcp = data.site_xpos[task.tcp_site]
        pending = [
            norm((np.asarray(clip.pos) - tcp)[:2])
            for clip, done in zip(task.placed_clips(data), routed, strict=True)
            if not done
        ]
        return {"clips_routed": float(sum(routed)), "clip_distance": min(pending, default=math.nan)}

    def at_goal(self, trace, held):
        """The held wire at a clip."""
        return held & (np.nan_to_num(trace["clip_distance"], nan=np.inf) <= CLIP_NEAR)

    def summarize(self, episode, steps):
        return {"final_clips_routed": final(episode["clips_routed"], steps)}

    def standard_variants(self):
        return [{"num_clips": n} for n in (1, 2, 3)]
