"""Arithmetic whose rounding does not depend on the CPU: use it for every number on an
episode's path.

Two parts of numpy pick their code per CPU, and the choices round differently:

- ``numpy.linalg``, ``numpy.dot``, ``@``, ``inner`` and ``einsum`` hand products to BLAS/LAPACK,
  and OpenBLAS picks a kernel per CPU (Haswell, SkylakeX, Zen, ...) that sums in its own order;
- numpy's own ``arctan2``, ``arccos``, ``arcsin``, ``arctan``, ``exp``, ``log``, ``power`` and
  ``tanh`` have AVX-512 and AVX2 versions that differ in the last bit from each other.

A last-bit difference grows, one chaotic contact later, into another outcome. So here:

- products and sums are element-wise numpy operations added in a fixed, explicit order (IEEE
  multiply and add round the same on every CPU and in every SIMD width);
- the one solve (damped least squares) uses MuJoCo's Cholesky routines, compiled C with no
  per-CPU dispatch;
- transcendental functions go through Python's ``math`` (the C library's libm, as MuJoCo's own
  C code does), one element at a time: the arrays on an episode's path are small.

Shapes follow numpy's broadcasting. The inner dimension of every product here is small (3 to 8),
so a Python loop over it costs a handful of numpy calls.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np


def _sum_last(products: np.ndarray) -> np.ndarray:
    total = products[..., 0]
    for k in range(1, products.shape[-1]):
        total = total + products[..., k]
    return total


def sum_in_order(x) -> np.ndarray:
    """Sum over the last axis, left to right: the same bits for one row as for many (numpy's
    own reduction changes its order with the array's shape)."""
    return _sum_last(np.asarray(x, dtype=float))


def dot(a, b) -> np.ndarray | float:
    """Inner product over the last axis, summed left to right. Scalars for 1-D inputs."""
    total = _sum_last(np.asarray(a, dtype=float) * np.asarray(b, dtype=float))
    return float(total) if total.ndim == 0 else total


def norm(x, axis: int = -1, keepdims: bool = False) -> np.ndarray | float:
    """Euclidean norm over ``axis`` (default: the last), summed in index order."""
    x = np.asarray(x, dtype=float)
    if axis not in (-1, x.ndim - 1):
        x = np.moveaxis(x, axis, -1)
    length = np.sqrt(_sum_last(x * x))
    if keepdims:
        length = np.expand_dims(length, axis)
    return float(length) if length.ndim == 0 else length


def cross(a, b) -> np.ndarray:
    """The cross product of 3-vectors (broadcast over leading axes): the same products and
    differences as ``numpy.cross``, so the same bits, without its axis handling (a tenth of the
    time on one vector, where the experts call it)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def matmul(a, b) -> np.ndarray:
    """``a @ b`` with numpy's rules for 1-D operands and stacked (batched) matrices."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if b.ndim == 1:  # (..., m, k) @ (k,) -> (..., m); (k,) @ (k,) -> scalar
        return dot(a, b)
    if a.ndim == 1:  # (k,) @ (..., k, n) -> (..., n)
        return dot(np.swapaxes(b, -1, -2), a)
    products = a[..., :, :, None] * b[..., None, :, :]  # (..., m, k, n)
    total = products[..., :, 0, :]
    for k in range(1, a.shape[-1]):
        total = total + products[..., :, k, :]
    return total


def matvec(a, v) -> np.ndarray:
    """Stacked matrix-vector products: a (..., m, k), v (..., k) -> (..., m)."""
    a = np.asarray(a, dtype=float)
    return dot(a, np.asarray(v, dtype=float)[..., None, :])


def solve_spd(a, b) -> np.ndarray:
    """Solve ``a x = b`` for symmetric positive-definite ``a`` (..., n, n), ``b`` (..., n), one
    matrix at a time with MuJoCo's Cholesky factorization."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    n = a.shape[-1]
    stack = a.reshape(-1, n, n)
    rhs = np.broadcast_to(b, a.shape[:-1]).reshape(-1, n, 1)
    out = np.empty_like(rhs)
    for i in range(stack.shape[0]):
        factor = stack[i].copy()
        if mujoco.mju_cholFactor(factor, 0.0) < n:
            raise np.linalg.LinAlgError("matrix is not positive definite")
        mujoco.mju_cholSolve(out[i], factor, np.ascontiguousarray(rhs[i]))
    return out.reshape(a.shape[:-1])


def _elementwise(function, *args) -> np.ndarray | float:
    if all(isinstance(a, int | float) for a in args):
        return function(*args)
    arrays = [np.asarray(a, dtype=float) for a in args]
    if any(a.shape != arrays[0].shape for a in arrays):
        arrays = np.broadcast_arrays(*arrays)
    shape = arrays[0].shape
    out = np.array(list(map(function, *(a.ravel().tolist() for a in arrays))), dtype=float)
    return float(out[0]) if not shape else out.reshape(shape)


def arctan2(y, x) -> np.ndarray | float:
    return _elementwise(math.atan2, y, x)


def arccos(x) -> np.ndarray | float:
    return _elementwise(math.acos, x)


def arcsin(x) -> np.ndarray | float:
    return _elementwise(math.asin, x)


def tanh(x) -> np.ndarray | float:
    return _elementwise(math.tanh, x)


def exp(x) -> np.ndarray | float:
    return _elementwise(math.exp, x)
