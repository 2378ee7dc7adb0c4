"""UD time-update and covariance-bump kernels (notes/rimu.md §11.4–§11.7): P = U diag(d) Uᵀ.

Conventions as in :mod:`radical_rt.kernels.ud` (U (n, n) unit upper triangular, d (n,) > 0, in place,
no allocation, status codes of :mod:`radical_rt._jit`, state units; the shape, finiteness and
factorization helpers are shared from there). This module owns the time updates — Thornton's
MWGS (:func:`mwgs_time_update`) and the attitude-first structured update
(:func:`structured_time_update`) — the Agee-Turner rank-one updates (:func:`agee_turner`,
:func:`add_diagonal_noise`, the parameters' random-walk noise) and the covariance bumps and resets
(:func:`reset_leading_block`, :func:`scale_states`). References: see :mod:`radical_rt.kernels.ud`
(Bierman 1977; Thornton & Bierman 1980; Agee & Turner 1972).
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt._jit import ERR_NONFINITE, ERR_NOT_POSITIVE, ERR_SHAPE, OK, kernel
from radical_rt.kernels.ud import all_finite, d_status, has_shape, udu_inplace


@kernel
def mwgs_time_update(U, d, Phi, G, q, Y_work, Dw_work, c_work):
    """Time update U⁺D⁺U⁺ᵀ = Φ U D Uᵀ Φᵀ + G diag(q) Gᵀ in place by Thornton's modified weighted
    Gram-Schmidt (Thornton & Bierman 1980; Bierman 1977 ch. VI; §11.4).

    Phi (n, n), G (n, r), q (r,) ≥ 0; work Y_work (≥ n, ≥ n+r), Dw_work and c_work (≥ n+r,). The new
    U is built in U's strict lower triangle (transposed) and committed only on success, so an
    error (including a singular result, ERR_NOT_POSITIVE) leaves U and d unchanged.
    """
    n = d.shape[0]
    r = q.shape[0]
    w = n + r
    if (not (has_shape(U, n, n) and has_shape(Phi, n, n) and has_shape(G, n, r)) or Y_work.shape[0] < n
            or Y_work.shape[1] < w or Dw_work.shape[0] < w or c_work.shape[0] < w):
        return ERR_SHAPE
    if not (all_finite(Phi) and all_finite(G) and all_finite(q)):
        return ERR_NONFINITE
    for k in range(r):
        if q[k] < 0.0:
            return ERR_NOT_POSITIVE
    Y = Y_work
    for i in range(n):  # Y = [Φ U | G], U unit upper triangular
        for j in range(n):
            s = Phi[i, j]
            for k in range(j):
                s += Phi[i, k] * U[k, j]
            Y[i, j] = s
        for k in range(r):
            Y[i, n + k] = G[i, k]
            Dw_work[n + k] = q[k]
        Dw_work[i] = d[i]
    for j in range(n - 1, -1, -1):
        dj = 0.0
        for k in range(w):
            c_work[k] = Dw_work[k] * Y[j, k]
            dj += Y[j, k] * c_work[k]
        if not (dj > 0.0 and math.isfinite(dj)):
            for jj in range(n):
                for ii in range(jj):
                    U[jj, ii] = 0.0
            return ERR_NOT_POSITIVE
        for i in range(j):
            s = 0.0
            for k in range(w):
                s += Y[i, k] * c_work[k]
            uij = s / dj
            U[j, i] = uij
            for k in range(w):
                Y[i, k] -= uij * Y[j, k]
        Y[j, 0] = dj  # row j is no longer needed: keep d⁺_j there until the commit
    for j in range(n):
        d[j] = Y[j, 0]
        for i in range(j):
            U[i, j] = U[j, i]
            U[j, i] = 0.0
    return OK


def structured_work(n: int, m: int = 3) -> np.ndarray:
    """Work array (m, n + m) for :func:`structured_time_update` and :func:`reset_leading_block`."""
    return np.zeros((m, n + m))


@kernel
def structured_time_update(U, d, m, Phi_aa, Phi_ap, Q_aa, work):
    """Attitude-first structured time update (§11.5; Thornton & Bierman 1980 partitioning).

    Φ = [[Phi_aa (m, m), Phi_ap (m, n−m)], [0, I]], process noise Q_aa (m, m) symmetric PSD (upper
    triangle read) on the leading m states. New U[:m, m:] = Phi_aa U[:m, m:] + Phi_ap U[m:, m:];
    the leading block is refactored (§11.1) from Phi_aa U11 D1 U11ᵀ Phi_aaᵀ + Q_aa; U[m:, m:] and
    d[m:] are not touched. work: (m, ≥ n + m), see :func:`structured_work`. Transactional.
    """
    n = d.shape[0]
    p = n - m
    if (m < 1 or m > n or not (has_shape(U, n, n) and has_shape(Phi_aa, m, m) and has_shape(Phi_ap, m, p)
                                and has_shape(Q_aa, m, m)) or work.shape[0] < m or work.shape[1] < n + m):
        return ERR_SHAPE
    if not (all_finite(Phi_aa) and all_finite(Phi_ap) and all_finite(Q_aa)):
        return ERR_NONFINITE
    # work[:, :p] = B (new U12); work[:, p:n] = M = Phi_aa U11; work[:, n:n+m] = P11 → U11⁺
    for i in range(m):
        for j in range(p):  # B = Phi_aa U12 + Phi_ap U22 (U22 unit upper)
            s = Phi_ap[i, j]
            for k in range(m):
                s += Phi_aa[i, k] * U[k, m + j]
            for k in range(j):
                s += Phi_ap[i, k] * U[m + k, m + j]
            work[i, j] = s
        for j in range(m):
            s = Phi_aa[i, j]
            for k in range(j):
                s += Phi_aa[i, k] * U[k, j]
            work[i, p + j] = s
    for i in range(m):
        for k in range(i, m):
            s = Q_aa[i, k]
            for j in range(m):
                s += work[i, p + j] * d[j] * work[k, p + j]
            work[i, n + k] = s
    dcol = work[:, p]  # M is dead: its first column holds d⁺
    status = udu_inplace(work[:m, n:n + m], m, dcol)
    if status != OK:
        return status
    for i in range(m):
        for j in range(p):
            U[i, m + j] = work[i, j]
        for j in range(i + 1, m):
            U[i, j] = work[i, n + j]
        d[i] = dcol[i]
    return OK


@kernel
def _agee_turner_core(U, d, c, a, jtop):
    """Agee-Turner rank-one update over columns jtop … 0 (a[jtop+1:] must be zero)."""
    for j in range(jtop, 0, -1):
        s = a[j]
        if s == 0.0:
            continue  # nothing changes in column j
        dj = d[j]
        d[j] = dj + c * s * s
        beta = c / d[j]
        eta = s * beta
        c = beta * dj
        for i in range(j):
            a[i] -= s * U[i, j]
            U[i, j] += eta * a[i]
    d[0] += c * a[0] * a[0]


@kernel
def agee_turner(U, d, c, a, a_work):
    """Rank-one update U⁺D⁺U⁺ᵀ = U D Uᵀ + c a aᵀ, c ≥ 0, in place (Agee & Turner 1972; §11.7).

    U (n, n), d (n,), a (n,) (not modified; copied into a_work (n,)). c < 0 (a downdate: use
    :func:`bierman_update` instead) returns ERR_NOT_POSITIVE and changes nothing.
    """
    n = d.shape[0]
    if not has_shape(U, n, n) or a.shape[0] != n or a_work.shape[0] < n:
        return ERR_SHAPE
    if not (math.isfinite(c) and all_finite(a)):
        return ERR_NONFINITE
    if c < 0.0:
        return ERR_NOT_POSITIVE
    if c == 0.0 or n == 0:
        return OK
    for i in range(n):
        a_work[i] = a[i]
    _agee_turner_core(U, d, c, a_work, n - 1)
    return d_status(d)


@kernel
def add_diagonal_noise(U, d, idx, c, a_work):
    """P[idx[k], idx[k]] += c[k] for each k, by Agee-Turner with a = e_idx[k] (§11.7): only columns
    ≤ idx[k] are touched (≈ idx[k]² flops each). idx (K,) int, c (K,) ≥ 0, a_work (n,).
    Used for random-walk parameter process noise (c = q Δt) and additive covariance bumps.
    """
    n = d.shape[0]
    K = idx.shape[0]
    if not has_shape(U, n, n) or c.shape[0] != K or a_work.shape[0] < n:
        return ERR_SHAPE
    for k in range(K):
        if idx[k] < 0 or idx[k] >= n:
            return ERR_SHAPE
        if not math.isfinite(c[k]):
            return ERR_NONFINITE
        if c[k] < 0.0:
            return ERR_NOT_POSITIVE
    for k in range(K):
        if c[k] == 0.0:
            continue
        j = idx[k]
        for i in range(j):
            a_work[i] = 0.0
        a_work[j] = 1.0
        _agee_turner_core(U, d, c[k], a_work, j)
    return d_status(d)


@kernel
def reset_leading_block(U, d, m, P0, work):
    """Warm-start reset (§11.6): U[:m, m:] ← 0 (no attitude-parameter cross-covariance) and the
    leading block ← UD factors of P0 (m, m) SPD. U[m:, m:] and d[m:] are not touched (bit-for-bit).
    work: (≥ m, ≥ m + 1), e.g. :func:`structured_work`. Transactional.
    """
    n = d.shape[0]
    if m < 1 or m > n or not (has_shape(U, n, n) and has_shape(P0, m, m)) or work.shape[0] < m \
            or work.shape[1] < m + 1:
        return ERR_SHAPE
    if not all_finite(P0):
        return ERR_NONFINITE
    for i in range(m):
        for j in range(m):
            work[i, j] = P0[i, j] if j >= i else 0.0
    dcol = work[:, m]
    status = udu_inplace(work[:m, :m], m, dcol)
    if status != OK:
        return status
    for i in range(m):
        for j in range(m):
            U[i, j] = work[i, j] if j >= i else 0.0
        for j in range(m, n):
            U[i, j] = 0.0
        d[i] = dcol[i]
    return OK


@kernel
def scale_states(U, d, s):
    """Multiplicative bump P ← S P S, S = diag(s), s (n,) > 0 (§11.7): U_ij ← s_i U_ij / s_j,
    d_j ← s_j² d_j. Correlation coefficients are kept."""
    n = d.shape[0]
    if not has_shape(U, n, n) or s.shape[0] != n:
        return ERR_SHAPE
    if not all_finite(s):
        return ERR_NONFINITE
    for i in range(n):
        if not s[i] > 0.0:
            return ERR_NOT_POSITIVE
    for j in range(n):
        for i in range(j):
            U[i, j] = s[i] * U[i, j] / s[j]
        d[j] *= s[j] * s[j]
    return d_status(d)
