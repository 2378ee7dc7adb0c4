"""The numbers of one excitation-monitor step (:mod:`radical_rt.engine.excitation`) from the
covariance, in one compiled call.

Written out as loops in a fixed order (no BLAS or LAPACK, whose kernels differ between CPUs): the
same bits on every machine. :func:`excitation_numbers` returns, from P (ns, ns):

* the log variances ln max(P_ii, 1e-300) of every state;
* the joint term of the scaled sense axes: ln det of their covariance block normalised to unit
  diagonal (a Cholesky factorisation; the block of a covariance is positive definite) plus the
  sum of their log variances — the log det of the block itself, computed where it is well
  conditioned; without a factorisation (the block not numerically positive definite) the sum
  alone;
* the variance of each row of a linear map G (m, ns) of the state, diag(G P Gᵀ) (the sense axes'
  components along the body axes).
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt._jit import kernel

_VAR_FLOOR = 1e-300  # variances below it (≤ 0 after rounding) are taken as this


@kernel
def _log_var(v):
    """ln max(v, 1e-300), NaN for NaN (as numpy's maximum and log)."""
    if v != v:
        return v
    return math.log(v if v > _VAR_FLOOR else _VAR_FLOOR)


@kernel
def unit_logdet(P, idx, work):
    """(ok, ln det C) of C = the block P[idx][:, idx] scaled to a unit diagonal, by Cholesky in
    work (m, m); ok False (the value 0) when C is not numerically positive definite or P has a
    non-positive variance there."""
    m = idx.shape[0]
    for a in range(m):
        if not P[idx[a], idx[a]] > 0.0:
            return False, 0.0
    for a in range(m):
        for b in range(m):
            work[a, b] = P[idx[a], idx[b]] / math.sqrt(P[idx[a], idx[a]] * P[idx[b], idx[b]])
    ld = 0.0
    for j in range(m):
        s = work[j, j]
        for k in range(j):
            s -= work[j, k] * work[j, k]
        if not s > 0.0:
            return False, 0.0
        ljj = math.sqrt(s)
        work[j, j] = ljj
        ld += 2.0 * math.log(ljj)
        for i in range(j + 1, m):
            s = work[i, j]
            for k in range(j):
                s -= work[i, k] * work[j, k]
            work[i, j] = s / ljj
    return True, ld


@kernel
def excitation_numbers(P, axis_idx, G, lv, row_var, work):
    """P (ns, ns) covariance; axis_idx (m,) int64 the states of the scaled sense axes; G (r, ns)
    (r may be 0). Out: lv (ns + 1,): ln variance of each state, then the axes' joint term
    (module docstring); row_var (r,) diag(G P Gᵀ) over G's non-zero entries (a sparse G: the
    rows of a few states each). work (m, m) scratch."""
    ns = P.shape[0]
    for i in range(ns):
        lv[i] = _log_var(P[i, i])
    lv_axes = 0.0
    for a in range(axis_idx.shape[0]):
        lv_axes += lv[axis_idx[a]]
    ok, ld = unit_logdet(P, axis_idx, work)
    lv[ns] = ld + lv_axes if ok else lv_axes
    for r in range(G.shape[0]):
        s = 0.0
        for c in range(ns):
            if G[r, c] != 0.0:
                x = 0.0
                for k in range(ns):
                    if G[r, k] != 0.0:
                        x += G[r, k] * P[k, c]
                s += x * G[r, c]
        row_var[r] = s


def excitation_work(m: int) -> np.ndarray:
    """The scratch array of :func:`excitation_numbers` for m sense-axis states."""
    return np.empty((m, m))
