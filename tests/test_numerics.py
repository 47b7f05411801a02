"""wirecraft.numerics against numpy's own results, and a guard that keeps CPU-dependent numpy
calls off an episode's path (see the module's docstring for why)."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from wirecraft import numerics

SRC = Path(__file__).resolve().parents[1] / "src" / "wirecraft"

# Code that never runs inside an episode: learning (torch), plots, reports, dataset statistics
# after the fact, the command line, benchmarks of speed.
OFF_THE_EPISODE_PATH = (
    "rl/",
    "evaluation/report.py",
    "evaluation/video.py",
    "bench/",
    "cli.py",
    "numerics.py",
)
# numpy functions whose result depends on the CPU: BLAS/LAPACK, or numpy's own per-CPU SIMD
# transcendentals (measured: AVX-512 and AVX2 versions differ in the last bit).
CPU_DEPENDENT = {
    "dot", "vdot", "inner", "matmul", "einsum", "tensordot", "linalg",
    "arctan2", "arctan", "arcsin", "arccos", "exp", "expm1", "log", "log1p", "log2", "log10",
    "power", "float_power", "tanh", "sinh", "cosh", "arcsinh", "arccosh", "arctanh", "tan",
    "cbrt", "exp2",
}  # fmt: skip


def _offences(path: Path) -> list[str]:
    tree = ast.parse(path.read_text())
    found = []
    for node in ast.walk(tree):
        where = f"{path.relative_to(SRC)}:{getattr(node, 'lineno', '?')}"
        if isinstance(node, ast.BinOp | ast.AugAssign) and isinstance(node.op, ast.MatMult):
            found.append(f"{where} uses @")
        elif isinstance(node, ast.Attribute) and node.attr in CPU_DEPENDENT:
            base = node.value
            if isinstance(base, ast.Name) and base.id in ("np", "numpy"):
                found.append(f"{where} uses np.{node.attr}")
            elif node.attr == "dot":
                found.append(f"{where} uses .dot")
    return found


def test_no_cpu_dependent_numpy_on_the_episode_path():
    offences = []
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC).as_posix()
        if any(rel.startswith(skip) for skip in OFF_THE_EPISODE_PATH):
            continue
        offences += _offences(path)
    assert not offences, "use wirecraft.numerics instead:\n" + "\n".join(offences)


def test_the_guard_sees_each_kind_of_offence(tmp_path):
    sample = tmp_path / "sample.py"
    sample.write_text(
        "import numpy as np\n"
        "a = np.eye(3) @ np.eye(3)\n"
        "b = np.linalg.norm(a)\n"
        "c = a.dot(a)\n"
        "d = np.arctan2(1.0, 2.0)\n"
        "e = np.cross(a, a) + np.sin(a)\n"
    )
    global SRC
    saved, SRC = SRC, tmp_path
    try:
        found = _offences(sample)
    finally:
        SRC = saved
    kinds = sorted(line.split(" uses ")[1] for line in found)
    assert kinds == [".dot", "@", "np.arctan2", "np.linalg"]


RNG = np.random.default_rng(0)


@pytest.mark.parametrize(
    ("a", "b"),
    [
        (RNG.normal(size=(5, 6, 7)), RNG.normal(size=(5, 7, 4))),
        (RNG.normal(size=(6, 7)), RNG.normal(size=(7, 3))),
        (RNG.normal(size=(5, 6, 7)), RNG.normal(size=7)),
        (RNG.normal(size=7), RNG.normal(size=(5, 7, 4))),
        (RNG.normal(size=3), RNG.normal(size=3)),
    ],
)
def test_matmul_matches_numpy(a, b):
    ours = numerics.matmul(a, b)
    np.testing.assert_allclose(ours, a @ b, rtol=1e-12, atol=1e-12)
    assert np.shape(ours) == np.shape(a @ b)


def test_dot_and_norm_match_numpy_and_give_floats_for_vectors():
    x = RNG.normal(size=(4, 5, 3))
    np.testing.assert_allclose(numerics.norm(x, axis=1), np.linalg.norm(x, axis=1), rtol=1e-14)
    np.testing.assert_allclose(
        numerics.norm(x, axis=-1, keepdims=True), np.linalg.norm(x, axis=-1, keepdims=True)
    )
    assert numerics.norm([3.0, 4.0]) == 5.0 and isinstance(numerics.norm([3.0, 4.0]), float)
    assert numerics.dot([1.0, 2.0, 3.0], [4.0, 5.0, 6.0]) == 32.0
    np.testing.assert_allclose(numerics.dot(x, x[0, 0]), x @ x[0, 0], rtol=1e-14)


@pytest.mark.parametrize(
    ("a", "b"),
    [
        (RNG.normal(size=3), RNG.normal(size=3)),
        (RNG.normal(size=(50, 3)), RNG.normal(size=(50, 3))),
        (RNG.normal(size=(4, 5, 3)), RNG.normal(size=3)),
        ([0.0, 0.0, 1.0], RNG.normal(size=(6, 3))),
    ],
)
def test_cross_is_numpys_bit_for_bit(a, b):
    ours = numerics.cross(a, b)
    assert ours.shape == np.cross(a, b).shape
    assert np.array_equal(ours, np.cross(a, b))


def test_the_sum_order_is_fixed_left_to_right():
    # 1e16 + 1 - 1e16 is 0 when added left to right and 1 when the last two pair first.
    assert numerics.dot([1e16, 1.0, -1e16], [1.0, 1.0, 1.0]) == 0.0


def test_solve_spd_solves_and_refuses_a_singular_matrix():
    jac = RNG.normal(size=(3, 6, 7))
    gram = jac @ jac.transpose(0, 2, 1) + 1e-4 * np.eye(6)
    rhs = RNG.normal(size=(3, 6))
    x = numerics.solve_spd(gram, rhs)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", gram, x), rhs, atol=1e-9)
    np.testing.assert_allclose(numerics.solve_spd(gram[1], rhs[1]), x[1], rtol=1e-12)
    with pytest.raises(np.linalg.LinAlgError):
        numerics.solve_spd(np.zeros((3, 3)), np.ones(3))


def test_transcendentals_are_libm_element_by_element():
    y, x = RNG.normal(size=(2, 4, 3))
    got = numerics.arctan2(y, x)
    assert got.shape == (4, 3)
    assert all(got[i, j] == math.atan2(y[i, j], x[i, j]) for i in range(4) for j in range(3))
    assert numerics.arccos(0.5) == math.acos(0.5) and isinstance(numerics.arccos(0.5), float)
    assert numerics.tanh(np.array([0.3]))[0] == math.tanh(0.3)
    np.testing.assert_allclose(numerics.arcsin([0.1, 0.2]), np.arcsin([0.1, 0.2]), rtol=1e-15)
