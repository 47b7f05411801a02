"""Where a result came from: recorded in every result file (evaluation and benchmark JSON, dataset
metadata, training run directories), so two results can be checked for comparability.

Two results are comparable when their ``benchmark_version`` (and ``golden_sha256``) agree: the
golden rollouts (``wirecraft.golden``) fix what the scripted episodes do. The rest says how the
result was made: the code's commit, the package versions, the CPU and the threads.
"""

from __future__ import annotations

import functools
import importlib.metadata
import os
import platform
import subprocess
from pathlib import Path

PACKAGES = (
    "wirecraft",
    "mujoco",
    "mujoco-warp",
    "warp-lang",
    "numpy",
    "gymnasium",
    "torch",
    "lerobot",
)


def _version(package: str) -> str | None:
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(("model name", "Model")):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def source_commit(package_dir: Path) -> str | None:
    """The git commit of a source checkout of WireCraft (``+dirty`` with uncommitted changes
    to tracked files); None for an installed wheel (also one inside someone's repository,
    where the package's files are not tracked) or without git."""

    def git(*args: str) -> str:
        return subprocess.run(
            ["git", "-C", str(package_dir), *args],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()

    try:
        git("ls-files", "--error-unmatch", "__init__.py")
        commit = git("rev-parse", "HEAD")
        dirty = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.SubprocessError):
        return None
    return commit + ("+dirty" if dirty else "")


@functools.cache
def _static() -> dict:
    from wirecraft import golden

    golden_file = golden.GOLDEN_FILE
    version = golden.load_golden()["benchmark_version"] if golden_file.exists() else None
    return {
        "benchmark_version": version,
        "golden_sha256": golden.golden_file_sha256(),
        "git_commit": source_commit(Path(__file__).resolve().parent),
        "packages": {name: _version(name) for name in PACKAGES},
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpu": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "openblas_coretype": os.environ.get("OPENBLAS_CORETYPE"),
    }


def provenance(threads: int | None = None, **extra) -> dict:
    """The provenance record: ``threads`` is the number of simulation threads or workers the
    result used (None: not applicable); ``extra`` adds job-specific fields."""
    return {**_static(), "threads": threads, **extra}
