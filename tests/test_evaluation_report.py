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
