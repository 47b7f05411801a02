"""What the evaluation measures for channel seating: the fraction of the wire inside the
channel and the ``not_seated`` failure label."""

from __future__ import annotations

import numpy as np

from wirecraft.tasks.metrics import TaskMetrics, final, metrics_of
from wirecraft.tasks.seating.options import CHANNELS
from wirecraft.tasks.seating.task import SUCCESS_FRACTION, SeatingTask

LAID_FRACTION = 0.2  # of the wire inside the channel: "laid"


@metrics_of(SeatingTask)
class SeatingMetrics(TaskMetrics):
    columns = ("fraction_inside",)
    failure_labels = {
        "not_seated": (
            f"the wire was laid (>= {100 * LAID_FRACTION:g}% inside the channel at some step) "
            f"but is < {100 * SUCCESS_FRACTION:g}% inside at the end"
        ),
    }
    trace_plots = (
        ("fraction_inside", "fraction inside", 1.0, (0.0, 1.0)),
        ("fixture_force", "wire-channel force (N)", 1.0, None),
        ("wire_tension", "wire tension (N)", 1.0, None),
        ("min_bend_radius", "min bend radius (mm)", 1000.0, (0.0, 200.0)),
    )
    episode_columns = ("final_fraction_inside",)

    def at_goal(self, trace, held):
        """The wire laid into the channel."""
        del held
        return np.nan_to_num(trace["fraction_inside"]) >= LAID_FRACTION

    def summarize(self, episode, steps):
        return {"final_fraction_inside": final(episode["fraction_inside"], steps)}

    def standard_variants(self):
        return [{"channel": c} for c in CHANNELS]
