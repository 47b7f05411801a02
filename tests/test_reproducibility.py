"""Same seed, same episode on every x86-64 CPU with AVX2 and FMA, and the golden-rollout gate.

Each golden cell (every task family with every wire model, each robot in every family) is a
480-step scripted episode fingerprinted over its actions, qpos, qvel, observations and rewards.
They run in subprocesses under several OpenBLAS kernels (``OPENBLAS_CORETYPE``), with numpy's
AVX-512 code switched off in one of them (``NPY_DISABLE_CPU_FEATURES``) and with 1 or 2 BLAS
threads: the fingerprints must agree bit for bit, and equal the committed golden file.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from pathlib import Path

import pytest

from wirecraft import golden


def _cpu_flags() -> set[str]:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    line = next((ln for ln in text.splitlines() if ln.startswith("flags")), "")
    return set(line.split(":", 1)[-1].split())


def _numpy_avx512() -> list[str]:
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__

    return [f for f in __cpu_dispatch__ if f.startswith("AVX512") and __cpu_features__.get(f)]


# OpenBLAS kernel -> the CPU flags it needs (forcing a kernel the CPU lacks would crash).
KERNELS = {
    "Haswell": {"avx2", "fma"},
    "SkylakeX": {"avx512f", "avx512bw", "avx512vl", "avx512dq", "avx512cd"},
    "Sandybridge": {"avx"},
    "Zen": {"avx2", "fma"},
    "Nehalem": set(),
}


def _settings() -> dict[str, dict[str, str]]:
    flags = _cpu_flags()
    usable = [name for name, needs in KERNELS.items() if needs <= flags]
    settings = {}
    for i, kernel in enumerate(usable[:3]):
        env = {"OPENBLAS_CORETYPE": kernel, "OPENBLAS_NUM_THREADS": str(1 + i % 2)}
        if i == 2 and _numpy_avx512():
            env["NPY_DISABLE_CPU_FEATURES"] = " ".join(_numpy_avx512())
        settings[" ".join(f"{k}={v}" for k, v in env.items())] = env
    return settings


pytestmark = pytest.mark.skipif(
    platform.machine() not in ("x86_64", "AMD64"), reason="the kernels compared are x86-64's"
)


@pytest.fixture(scope="module")
def fingerprints_by_setting() -> dict[str, dict]:
    settings = _settings()
    if len(settings) < 3:
        pytest.skip(f"this CPU offers fewer than 3 OpenBLAS kernels to compare: {list(settings)}")
    command = [sys.executable, "-m", "wirecraft.golden", "--json"]
    runs = {
        name: subprocess.Popen(
            command,
            env={**os.environ, **env},
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for name, env in settings.items()
    }
    out = {}
    for name, run in runs.items():
        stdout, stderr = run.communicate(timeout=900)
        assert run.returncode == 0, f"{name}: {stderr[-2000:]}"
        out[name] = json.loads(stdout)
    return out


def test_every_golden_cell_is_the_same_episode_under_every_kernel(fingerprints_by_setting):
    (first_name, first), *others = fingerprints_by_setting.items()
    assert set(first) == set(golden.cells())
    differ = []
    for name, prints in others:
        differ += [
            f"{cell}: {first_name} vs {name} ({', '.join(golden.differences({cell: prints[cell]}, {cell: first[cell]}))})"  # noqa: E501
            for cell in golden.cells()
            if prints[cell]["sha256"] != first[cell]["sha256"]
        ]
    assert not differ, "\n".join(differ)


def test_the_episodes_are_the_golden_rollouts(fingerprints_by_setting):
    today = next(iter(fingerprints_by_setting.values()))
    changed = golden.differences(today, golden.load_golden()["cells"])
    assert not changed, (
        "scripted episodes changed; if that is meant, run `python -m wirecraft.golden --write` "
        "(it raises the benchmark version):\n" + "\n".join(changed)
    )


def test_the_gate_names_a_changed_cell_and_when_it_changed(tmp_path):
    stored = golden.load_golden()["cells"]
    cell = next(iter(stored))
    altered = {**stored, cell: {**stored[cell], "sha256": "0" * 64}}
    altered[cell]["checkpoints"] = ["x", *stored[cell]["checkpoints"][1:]]
    assert golden.differences(altered, stored) == [f"{cell}: differs within second 1"]
    assert golden.differences(stored, stored) == []


def test_writing_changed_fingerprints_raises_the_benchmark_version(tmp_path):
    path = tmp_path / "golden.json"
    path.write_text(json.dumps(golden.load_golden()))
    stored = golden.load_golden()
    same_version, changed = golden.write_golden(stored["cells"], path)
    assert (same_version, changed) == (stored["benchmark_version"], [])
    cell = next(iter(stored["cells"]))
    altered = {**stored["cells"], cell: {**stored["cells"][cell], "sha256": "1" * 64}}
    version, changed = golden.write_golden(altered, path)
    assert version == stored["benchmark_version"] + 1
    assert [line.split(":")[0] for line in changed] == [cell]
    assert json.loads(path.read_text())["cells"][cell]["sha256"] == "1" * 64
