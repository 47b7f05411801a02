"""Traces (Parquet), videos (MP4) and the HTML report, opened in headless Chromium."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from wirecraft import cli
from wirecraft.evaluation import diagnostics, report
from wirecraft.evaluation.traces import read_traces


@pytest.fixture(scope="module")
def report_dir(tmp_path_factory):
    """A report of two small runs (two connectors) with the traces and one video each."""
    folder = tmp_path_factory.mktemp("report")
    for connector in ("ethernet", "cuboid"):
        code = cli.main(
            [
                "eval",
                "--task",
                "insertion",
                "--connector",
                connector,
                "--policy",
                "zero",
                "--seeds",
                "2",
                "--episodes",
                "1",
                "--episode-seconds",
                "0.3",
                "--report",
                str(folder),
                "--json",
                str(folder / f"{connector}.json"),
                "--quiet",
            ]
        )
        assert code == 0
    return folder


def test_traces_hold_every_step_of_every_episode(report_dir):
    runs = report.load_runs(report_dir)
    assert len(runs) == 2
    for slug, payload in runs:
        table = read_traces(report_dir / "traces" / f"{slug}.parquet").to_pydict()
        assert set(diagnostics.columns("insertion")) <= set(table)
        steps = payload["protocol"]["episode_steps"]
        assert steps == 18
        for episode in payload["episodes"]:
            rows = [
                k
                for k in range(len(table["seed"]))
                if table["seed"][k] == episode["seed"] and table["episode"][k] == episode["episode"]
            ]
            assert len(rows) == steps  # no success: no retention steps
            assert [table["step"][k] for k in rows] == list(range(steps))
            assert np.isclose(table["time"][rows[-1]], steps / 60)
            depth = [table["insertion_depth"][k] for k in rows]
            assert depth[-1] == pytest.approx(episode["final_insertion_depth"], abs=1e-6)


def test_the_videos_decode_with_the_overlay_band(report_dir):
    import av

    videos = sorted(report_dir.glob("videos/*/*.mp4"))
    assert len(videos) == 2  # one per run: the first episode of the only label (no_grasp)
    with av.open(str(videos[0])) as container:
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    assert len(frames) == 1 + 18 // 2  # first frame, then every second control step
    assert frames[0].shape == (270, 630, 3)
    band = frames[-1][-12:, :, :].reshape(-1, 3).mean(axis=0)
    assert band[0] > 120 and band[1] < 90  # the red failure band at the bottom
    assert videos[0].with_suffix(".png").exists()  # the poster


def test_the_report_renders_in_headless_chromium_with_its_tables(report_dir, tmp_path):
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("chromium is not installed (make browser installs it)")
    playwright = pytest.importorskip("playwright.sync_api")
    errors: list[str] = []
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=["--no-sandbox"])
        page = browser.new_page(viewport={"width": 1280, "height": 900})
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto((report_dir / "index.html").as_uri())
        page.wait_for_load_state("networkidle")
        rows = page.locator("table#summary tr")
        assert rows.count() == 3  # header + two runs
        text = page.locator("table#summary").inner_text()
        assert "connector=cuboid" in text and "connector=ethernet" in text
        assert "no_grasp: 2" in text
        images = page.eval_on_selector_all(
            "img", "els => els.map(e => [e.getAttribute('src'), e.naturalWidth])"
        )
        assert len(images) == 4 and all(width > 100 for _, width in images)
        assert page.locator("video").count() == 2
        page.screenshot(path=str(tmp_path / "report.png"), full_page=True)
        browser.close()
    assert errors == []
    assert (tmp_path / "report.png").stat().st_size > 10_000


def test_the_report_keeps_the_json_documents(report_dir):
    for connector in ("ethernet", "cuboid"):
        document = json.loads((report_dir / f"{connector}.json").read_text())
        slug = report.run_slug(document)
        stored = json.loads((report_dir / "runs" / f"{slug}.json").read_text())
        assert stored["metrics"] == document["metrics"]
        assert stored["episodes"] == document["episodes"]
        assert all(path.startswith("videos/") for path in stored["videos"].values())


def _payload(policy: str, label: str | None = None) -> dict:
    payload = {
        "task": "insertion",
        "variant": "insertion/clearance=0.003/connector=ethernet",
        "policy": policy,
        "env_kwargs": {"robot": "ur5"},
        "protocol": {"reset_seeds": [[1]]},
    }
    if label is not None:
        payload["label"] = label
    return payload


def test_runs_of_lerobot_checkpoints_are_labelled_apart():
    act = "out/train/act_run/checkpoints/020000/pretrained_model"
    dp = "out/train/dp_run/checkpoints/020000/pretrained_model"
    runs = [("a", _payload(act)), ("b", _payload(dp)), ("c", _payload("zero", label="mine"))]
    labels = report.run_labels(runs)
    assert labels["a"].endswith("· act_run/020000") and labels["b"].endswith("· dp_run/020000")
    assert labels["c"].endswith("· mine")
    assert report.run_slug(runs[0][1]) != report.run_slug(runs[1][1])
    assert "act_run-020000" in report.run_slug(runs[0][1])
    # The same short name from two places: the full paths; the very same policy: numbered.
    twins = [("a", _payload("x/act/pretrained_model")), ("b", _payload("y/act/pretrained_model"))]
    labels = report.run_labels(twins)
    assert labels["a"].endswith("· x/act/pretrained_model") and labels["b"].endswith(
        "· y/act/pretrained_model"
    )
    same = [("a", _payload("zero")), ("b", _payload("zero")), ("c", _payload("zero"))]
    assert len(set(report.run_labels(same).values())) == 3
    assert report.run_labels(same)["c"].endswith("#3")


def test_eval_stores_the_label_given_or_derived(tmp_path):
    common = ["eval", "--task", "insertion", "--policy", "zero", "--seeds", "1", "--episodes"]
    common += ["1", "--episode-seconds", "0.05", "--quiet", "--json"]
    assert cli.main([*common, str(tmp_path / "a.json"), "--label", "baseline"]) == 0
    assert json.loads((tmp_path / "a.json").read_text())["label"] == "baseline"
    assert cli.main([*common, str(tmp_path / "b.json")]) == 0
    assert json.loads((tmp_path / "b.json").read_text())["label"] == "zero"


def test_trace_panels_fit_data_outside_their_usual_window(tmp_path):
    window = (-40.0, 25.0)  # insertion depth, mm
    far = np.full(50, -200.0)  # a plug that never nears the port
    limits, note = report.panel_limits(far, window)
    assert limits[0] < -200 < limits[1] and "no data" in note
    limits, note = report.panel_limits(np.r_[far, np.linspace(-30, 10, 50)], window)
    assert limits == window and "out of range: 50 below (50% of samples)" in note
    assert report.panel_limits(np.linspace(-30, 10, 50), window) == (window, None)
    assert report.panel_limits(far, None) == (None, None)
    # A whole plot of such an episode draws.
    import pyarrow as pa

    n = 30
    columns = {c: np.zeros(n) for c in diagnostics.columns("insertion")}
    columns.update(
        seed=np.zeros(n, int), episode=np.zeros(n, int), time=np.arange(n) / 60,
        stage=["episode"] * n, insertion_depth=np.full(n, -0.2),
    )  # fmt: skip
    path = report.plot_traces("insertion", pa.table(columns), tmp_path / "t.png", "far")
    assert path.stat().st_size > 10_000
