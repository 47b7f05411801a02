"""The HTML report of one or more evaluations: tables, plots, videos.

A report folder accumulates runs: ``add_run`` stores a run's JSON document, its traces
(Parquet) and its videos under a slug naming the variant, policy, robot and wire; ``build``
then (re)draws every plot and writes ``index.html`` from everything the folder holds, so
evaluating five connectors into the same folder gives one report comparing them.

Layout::

    DIR/index.html
    DIR/runs/SLUG.json         the payload of ``wirecraft eval --json``
    DIR/traces/SLUG.parquet    per-step traces (traces.py)
    DIR/videos/SLUG/*.mp4      chosen episodes (evaluation/video.py)
    DIR/plots/*.png            success by variant, failure labels, traces per run
"""

from __future__ import annotations

import hashlib
import html
import json
import re
from pathlib import Path

import numpy as np

from wirecraft.evaluation import diagnostics
from wirecraft.tasks import TASKS

METRIC_TITLES = {
    "success": "success",
    "reach_success": "SR reach",
    "insert_success": "SR insert",
    "retain_success": "retained",
    "success_at_end": "success at end",
}


def run_slug(payload: dict) -> str:
    """A file-name-safe id of a run: task, policy, robot, wire and a hash of the rest."""
    kwargs = payload.get("env_kwargs", {})
    identity = json.dumps(
        [payload["variant"], payload["policy"], kwargs, payload["protocol"].get("reset_seeds")],
        sort_keys=True,
    )
    digest = hashlib.sha1(identity.encode()).hexdigest()[:8]
    policy = policy_title(payload).replace("/", "-") or "policy"
    # The variant's option values, those at their defaults left out.
    defaults = TASKS.get(payload["task"]).Options.defaults()
    variant = [part.split("=", 1) for part in payload["variant"].split("/")[1:]]
    variant = [
        v for k, v in variant if v not in ("None", repr(defaults.get(k)), str(defaults.get(k)))
    ]
    variant = variant or ["default"]
    parts = [
        payload["task"],
        "-".join(variant),
        policy,
        kwargs.get("robot", ""),
        kwargs.get("wire", ""),
        digest,
    ]
    return re.sub(r"[^A-Za-z0-9_.=-]+", "-", "_".join(str(p) for p in parts if p != ""))


def policy_title(payload: dict) -> str:
    """The run's policy name: its ``label`` (``wirecraft eval --label``, else derived from the
    policy's path), or for documents without one, derived here."""
    from wirecraft.evaluation.policies import policy_label

    label = payload.get("label")
    return str(label) if label else policy_label(str(payload["policy"]))


def run_label(payload: dict, policy: str | None = None) -> str:
    """Short human name of a run for tables and plot axes (``policy``: the policy's name in
    it, default ``policy_title``)."""
    variant = payload["variant"].split("/", 1)
    details = variant[1].replace("/", ", ") if len(variant) > 1 else ""
    kwargs = payload.get("env_kwargs", {})
    extra = ", ".join(f"{k}={kwargs[k]}" for k in ("robot", "wire") if k in kwargs)
    policy = policy_title(payload) if policy is None else policy
    return f"{payload['task']} [{details}{', ' + extra if extra else ''}] · {policy}"


def run_labels(runs: list[tuple[str, dict]]) -> dict[str, str]:
    """slug -> a label distinct from every other run's: runs whose ``run_label`` coincide are
    named by their policy's full path, then numbered (#2, #3, ...) in the folder's order."""
    labels = {slug: run_label(payload) for slug, payload in runs}
    payloads = dict(runs)
    for name in set(labels.values()):
        same = [slug for slug in labels if labels[slug] == name]
        if len(same) < 2:
            continue
        full = {slug: run_label(payloads[slug], str(payloads[slug]["policy"])) for slug in same}
        if len(set(full.values())) == len(same):
            labels.update(full)
    seen: dict[str, int] = {}
    for slug, _ in runs:
        name = labels[slug]
        seen[name] = seen.get(name, 0) + 1
        if seen[name] > 1:
            labels[slug] = f"{name} #{seen[name]}"
    return labels


# -- folder bookkeeping -------------------------------------------------------------------------
def add_run(folder: str | Path, run, videos: dict[str, Path] | None = None) -> str:
    """Store the run (an ``EvaluationRun``) in the report folder; returns its slug.
    ``videos``: caption -> video file already written into ``folder/videos/SLUG``."""
    from wirecraft.evaluation.traces import write_traces

    folder = Path(folder)
    slug = run_slug(run.payload)
    (folder / "runs").mkdir(parents=True, exist_ok=True)
    document = dict(run.payload)
    document["videos"] = {
        caption: str(Path(path).relative_to(folder)) for caption, path in (videos or {}).items()
    }
    (folder / "runs" / f"{slug}.json").write_text(json.dumps(document, indent=2) + "\n")
    write_traces(folder / "traces" / f"{slug}.parquet", run.config.task, run.results)
    return slug


def load_runs(folder: str | Path) -> list[tuple[str, dict]]:
    folder = Path(folder)
    runs = []
    for path in sorted((folder / "runs").glob("*.json")):
        runs.append((path.stem, json.loads(path.read_text())))
    return runs


# -- plots ----------------------------------------------------------------------------------------
def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_success(runs: list[tuple[str, dict]], path: Path) -> Path:
    """Grouped bars: every metric of every run, mean +/- std over seeds, seeds as dots."""
    plt = _pyplot()
    labels = run_labels(runs)
    metrics = [m for m in METRIC_TITLES if any(m in p["metrics"] for _, p in runs)]
    fig, ax = plt.subplots(figsize=(max(6.0, 1.6 * len(runs) * len(metrics) / 2), 3.8))
    width = 0.8 / max(1, len(runs))
    for r, (slug, payload) in enumerate(runs):
        xs, means, stds = [], [], []
        for m, metric in enumerate(metrics):
            if metric not in payload["metrics"]:
                continue
            value = payload["metrics"][metric]
            x = m + (r - (len(runs) - 1) / 2) * width
            xs.append(x)
            means.append(100 * (value["mean"] or 0.0))
            stds.append(100 * (value["std"] or 0.0))
            seeds = [100 * v for v in value["per_seed"] if v is not None]
            ax.scatter([x] * len(seeds), seeds, s=9, color="black", zorder=3)
        ax.bar(xs, means, width * 0.95, yerr=stds, capsize=3, label=labels[slug])
    ax.set_xticks(range(len(metrics)), [METRIC_TITLES[m] for m in metrics])
    ax.set_ylabel("rate (%), mean ± std over seeds")
    ax.set_ylim(0, 105)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=1, frameon=False)
    ax.set_title("Success by variant")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_failures(runs: list[tuple[str, dict]], path: Path) -> Path:
    """Stacked horizontal bars: failure labels per run."""
    plt = _pyplot()
    taxonomy = list(diagnostics.all_labels())
    labels = [lab for lab in taxonomy if any(lab in p["failures"] for _, p in runs)]
    fig, ax = plt.subplots(figsize=(7.5, 0.6 + 0.5 * max(2, len(runs))))
    cmap = plt.get_cmap("tab20")
    run_names = run_labels(runs)
    names = [run_names[slug] for slug, _ in runs]
    left = np.zeros(len(runs))
    for label in labels:
        counts = np.array([p["failures"].get(label, 0) for _, p in runs], float)
        colour = cmap(taxonomy.index(label) % 20)
        ax.barh(range(len(runs)), counts, left=left, color=colour, label=label)
        left += counts
    ax.set_yticks(range(len(runs)), names, fontsize=7)
    ax.set_xlabel("failed episodes")
    if not labels:
        ax.text(0.5, 0.5, "no failures", transform=ax.transAxes, ha="center", va="center")
    else:
        ax.legend(fontsize=7, loc="lower right")
    ax.set_title("Failure labels")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def panel_limits(values: np.ndarray, window) -> tuple[tuple[float, float] | None, str | None]:
    """The y limits of a trace panel and a note for it.  ``window``: the panel's usual range
    (the interesting one: a dropped plug is 20 cm from the port), or None (matplotlib's own
    limits).  When no finite value falls in the window (a policy that never nears the port)
    the limits fit the data instead, noted; when some values lie outside it, they are noted
    as out of range."""
    if window is None:
        return None, None
    lo, hi = window
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    if not values.size:
        return (lo, hi), None
    inside = (values >= lo) & (values <= hi)
    if inside.all():
        return (lo, hi), None
    if not inside.any():
        low, high = float(values.min()), float(values.max())
        # At least a quarter of the window's span, so a flat trace is not magnified into noise.
        span = max(high - low, (hi - lo) / 4)
        pad = 0.05 * span + (span - (high - low)) / 2
        return (low - pad, high + pad), f"no data in {lo:g}..{hi:g}: axis fits the data"
    above, below = int((values > hi).sum()), int((values < lo).sum())
    where = " and ".join(
        text for count, text in ((above, f"{above} above"), (below, f"{below} below")) if count
    )
    return (lo, hi), f"out of range: {where} ({100 * (~inside).mean():.0f}% of samples)"


def plot_traces(task: str, table, path: Path, title: str) -> Path:
    """Per-step traces of every episode (green: retained, orange: succeeded but not
    retained, red: failed); the retention steps after the dashed line."""
    plt = _pyplot()
    panels = TASKS.get(task).metrics.trace_plots
    columns = table.to_pydict()
    seeds = np.asarray(columns["seed"])
    episodes = np.asarray(columns["episode"])
    times = np.asarray(columns["time"])
    stages = np.asarray(columns["stage"])
    success = np.asarray(columns["success"], float)
    outcome_colour = {"retained": "tab:green", "success": "tab:orange", "failed": "tab:red"}
    cols = 2 if len(panels) > 1 else 1
    rows_of_panels = -(-len(panels) // cols)
    fig, axes = plt.subplots(
        rows_of_panels, cols, figsize=(4.75 * cols, 2.8 * rows_of_panels), sharex=True,
        squeeze=False,
    )  # fmt: skip
    for ax in axes.ravel()[len(panels) :]:
        ax.set_visible(False)
    keys = sorted(set(zip(seeds.tolist(), episodes.tolist(), strict=True)))
    horizon = times[stages == "episode"].max(initial=0.0)
    for ax, (column, label, scale, limits) in zip(axes.ravel(), panels, strict=False):
        values = np.asarray(columns[column], float) * scale
        for seed, episode in keys:
            rows = (seeds == seed) & (episodes == episode)
            ok = np.nanmax(np.where(stages[rows] == "episode", success[rows], 0.0)) > 0.5
            retained = ok and stages[rows][-1] == "retention" and success[rows][-1] > 0.5
            outcome = "retained" if retained else "success" if ok else "failed"
            colour = outcome_colour[outcome]
            ax.plot(times[rows], values[rows], lw=0.8, alpha=0.6, color=colour)
        ax.axvline(horizon, color="grey", ls="--", lw=0.8)
        finite = values[np.isfinite(values)]
        ylim, note = panel_limits(finite, limits)
        if ylim is not None:
            ax.set_ylim(*ylim)
        if note:
            ax.text(
                0.99, 0.97, note, transform=ax.transAxes, ha="right", va="top", fontsize=7,
                color="dimgrey",
            )  # fmt: skip
        elif finite.size and limits is None and finite.max() > 3 * np.percentile(finite, 99.5) > 0:
            # A few numerical spikes would flatten every curve: clip them (noted on the axis).
            ax.set_ylim(0, 1.2 * np.percentile(finite, 99.5))
            label += " (spikes clipped)"
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time (s); retention check after the dashed line")
    handles = [plt.Line2D([], [], color=c, label=k) for k, c in outcome_colour.items()]
    axes[0, 0].legend(handles=handles, fontsize=7, loc="upper left")
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


# -- HTML ------------------------------------------------------------------------------------------
CSS = """
body { font-family: system-ui, sans-serif; margin: 24px; color: #222; max-width: 1200px; }
table { border-collapse: collapse; margin: 8px 0 20px; font-size: 13px; }
th, td { border: 1px solid #ccc; padding: 3px 8px; text-align: left; }
th { background: #f0f0f0; }
td.ok { color: #17702f; } td.bad { color: #b3261e; }
img { max-width: 100%; border: 1px solid #ddd; }
figure { display: inline-block; margin: 6px; vertical-align: top; }
figcaption { font-size: 12px; color: #555; }
details { margin: 8px 0; }
code { background: #f4f4f4; padding: 0 3px; }
"""


def _fmt(metric: dict | None) -> str:
    if not metric or metric.get("mean") is None:
        return "–"
    return f"{100 * metric['mean']:.1f} ± {100 * (metric['std'] or 0):.1f}"


def _summary_table(runs) -> str:
    labels = run_labels(runs)
    metrics = [m for m in METRIC_TITLES if any(m in p["metrics"] for _, p in runs)]
    head = "".join(f"<th>{METRIC_TITLES[m]} (%)</th>" for m in metrics)
    rows = []
    for slug, payload in runs:
        cells = "".join(f"<td>{_fmt(payload['metrics'].get(m))}</td>" for m in metrics)
        failures = ", ".join(f"{k}: {v}" for k, v in payload["failures"].items()) or "none"
        proto = payload["protocol"]
        rows.append(
            f"<tr><td><a href='#{slug}'>{html.escape(labels[slug])}</a></td>"
            f"<td>{proto['seeds']} × {proto['episodes_per_seed']}</td>{cells}"
            f"<td>{html.escape(failures)}</td></tr>"
        )
    return (
        "<table id='summary'><tr><th>run</th><th>seeds × episodes</th>"
        f"{head}<th>failures</th></tr>{''.join(rows)}</table>"
    )


def _episodes_table(payload: dict) -> str:
    task = payload["task"]
    extra = TASKS.get(task).metrics.episode_columns
    cols = (
        "seed",
        "episode",
        "success",
        "failure",
        "retain_success",
        "retain_failure",
        *extra,
        "max_wire_tension",
        "min_bend_radius",
        "final_phase",
    )
    head = "".join(f"<th>{c}</th>" for c in cols)
    rows = []
    for ep in payload["episodes"]:
        cells = []
        for c in cols:
            value = ep.get(c)
            css = ""
            if isinstance(value, bool):
                css = " class='ok'" if value else " class='bad'"
            if isinstance(value, float):
                value = f"{value:.4g}"
            cells.append(f"<td{css}>{html.escape('–' if value is None else str(value))}</td>")
        rows.append(f"<tr>{''.join(cells)}</tr>")
    return f"<table class='episodes'><tr>{head}</tr>{''.join(rows)}</table>"


def _taxonomy_table() -> str:
    rows = "".join(
        f"<tr><td><code>{label}</code></td><td>{', '.join(families)}</td>"
        f"<td>{html.escape(text)}</td></tr>"
        for label, (families, text) in diagnostics.all_labels().items()
    )
    return f"<table><tr><th>label</th><th>tasks</th><th>meaning</th></tr>{rows}</table>"


def _poster(folder: Path, src: str) -> str:
    poster = Path(src).with_suffix(".png")
    return f" poster='{html.escape(str(poster))}'" if (folder / poster).exists() else ""


def build(folder: str | Path) -> Path:
    """Draw the plots and write ``folder/index.html`` from every run stored in the folder."""
    from wirecraft.evaluation.traces import read_traces

    folder = Path(folder)
    runs = load_runs(folder)
    if not runs:
        raise ValueError(f"{folder}: no evaluation runs stored (runs/*.json)")
    plots = folder / "plots"
    plots.mkdir(parents=True, exist_ok=True)
    plot_success(runs, plots / "success.png")
    plot_failures(runs, plots / "failures.png")
    sections = []
    labels = run_labels(runs)
    for slug, payload in runs:
        trace_file = folder / "traces" / f"{slug}.parquet"
        parts = [f"<h2 id='{slug}'>{html.escape(labels[slug])}</h2>"]
        proto = payload["protocol"]
        parts.append(
            "<p>policy <code>{}</code>, environment <code>{}</code>, protocol {} ({} seeds × {} "
            "episodes, {} steps; retention pull {} N){}</p>".format(
                html.escape(str(payload["policy"])),
                html.escape(json.dumps(payload["env_kwargs"])),
                proto["version"],
                proto["seeds"],
                proto["episodes_per_seed"],
                proto["episode_steps"],
                proto["retain_force"],
                ""
                if proto.get("held_out_seed") is None
                else f", held-out list --seed {proto['held_out_seed']}",
            )
        )
        if trace_file.exists():
            image = plots / f"traces_{slug}.png"
            plot_traces(payload["task"], read_traces(trace_file), image, labels[slug])
            parts.append(f"<img src='plots/{image.name}' alt='traces {slug}'>")
            parts.append(f"<p>Traces: <a href='traces/{slug}.parquet'>{slug}.parquet</a></p>")
        videos = payload.get("videos") or {}
        if videos:
            figures = "".join(
                f"<figure><video controls muted preload='none' width='420' "
                f"src='{html.escape(src)}'{_poster(folder, src)}></video>"
                f"<figcaption>{html.escape(caption)}</figcaption></figure>"
                for caption, src in videos.items()
            )
            parts.append(f"<div class='videos'>{figures}</div>")
        parts.append(f"<details><summary>episodes</summary>{_episodes_table(payload)}</details>")
        sections.append("\n".join(parts))
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>WireCraft evaluation</title>
<style>{CSS}</style></head><body>
<h1>WireCraft evaluation</h1>
<p>Success rates in %, mean ± std over seeds. "SR reach" / "SR insert" / "success": at any
step of the episode (the reference's protocol); "success at end": at its last step;
"retained": still successful after the retention check (release, retreat, pull).</p>
{_summary_table(runs)}
<img src="plots/success.png" alt="success by variant">
<img src="plots/failures.png" alt="failure labels">
{"".join(sections)}
<h2>Failure labels</h2>
{_taxonomy_table()}
</body></html>
"""
    index = folder / "index.html"
    index.write_text(page)
    return index
