"""Dense-covariance kernels of the engine's reference (tests/oracles/dense_engine.py): the window
time update, the diagonal noise, the leading-block reset and the gated (Joseph-form, Schmidt)
update on P (ns, ns) instead of the UD factors."""

from __future__ import annotations

import math

import numpy as np

from radical_rt._jit import ERR_NONFINITE, ERR_NOT_POSITIVE, ERR_SHAPE, OK, kernel


@kernel
def dense_time_update(P, m, Phi_aa, Phi_ap, Q_aa, T):
    """P ← ΦPΦᵀ + Q for Φ = [[Phi_aa (m, m), Phi_ap (m, n−m)], [0, I]], Q nonzero on the leading
    (m, m) block only (upper triangle of Q_aa read). T (m, n) work. Only the leading m rows and
    columns change."""
    n = P.shape[0]
    p = n - m
    if Phi_aa.shape[0] != m or Phi_ap.shape[1] != p or T.shape[0] < m or T.shape[1] < n:
        return ERR_SHAPE
    for i in range(m):  # T = [Φ_aa Φ_ap] P  (the new leading rows before Φᵀ on the right)
        for j in range(n):
            s = 0.0
            for k in range(m):
                s += Phi_aa[i, k] * P[k, j]
            for k in range(p):
                s += Phi_ap[i, k] * P[m + k, j]
            T[i, j] = s
    for i in range(m):
        for j in range(p):  # P_ap ← (ΦP)_ap
            P[i, m + j] = T[i, m + j]
            P[m + j, i] = T[i, m + j]
        for j in range(i, m):  # P_aa ← T Φᵀ (leading columns) + Q_aa
            s = Q_aa[i, j] if j >= i else Q_aa[j, i]
            for k in range(m):
                s += T[i, k] * Phi_aa[j, k]
            for k in range(p):
                s += T[i, m + k] * Phi_ap[j, k]
            P[i, j] = s
            P[j, i] = s
    for i in range(m):
        if not (P[i, i] > 0.0 and math.isfinite(P[i, i])):
            return ERR_NOT_POSITIVE
    return OK


@kernel
def dense_add_diagonal(P, idx, c):
    """P[idx[k], idx[k]] += c[k] (c ≥ 0)."""
    for k in range(idx.shape[0]):
        if not math.isfinite(c[k]):
            return ERR_NONFINITE
        if c[k] < 0.0:
            return ERR_NOT_POSITIVE
    for k in range(idx.shape[0]):
        P[idx[k], idx[k]] += c[k]
    return OK


@kernel
def dense_reset_leading(P, m, P0):
    """Leading (m, m) block ← P0 (symmetrized), its cross-covariance ← 0."""
    n = P.shape[0]
    for i in range(m):
        for j in range(n):
            P[i, j] = 0.0
            P[j, i] = 0.0
    for i in range(m):
        for j in range(m):
            P[i, j] = 0.5 * (P0[i, j] + P0[j, i])
    return OK


@kernel
def dense_innovation_test(P, dx, H, z, rdiag, S, innov, sig, PHt):
    """innov = z − H dx, S = HPHᵀ + R, sig = sqrt(diag S); returns the NIS νᵀS⁻¹ν. PHt (n, m)."""
    m, n = H.shape
    for a in range(m):
        s = 0.0
        for j in range(n):
            s += H[a, j] * dx[j]
        innov[a] = z[a] - s
        for i in range(n):
            acc = 0.0
            for j in range(n):
                acc += P[i, j] * H[a, j]
            PHt[i, a] = acc
    for a in range(m):
        for b in range(m):
            acc = rdiag[a] if a == b else 0.0
            for j in range(n):
                acc += H[a, j] * PHt[j, b]
            S[a, b] = acc
        sig[a] = np.sqrt(S[a, a]) if S[a, a] > 0 else 0.0
    return innov @ np.linalg.solve(S, innov)


@kernel
def dense_gated_update(P, dx, H, z, rdiag, gate, edit_enabled, consider, S, innov, sig, PHt, b, k):
    """Gated sequential update of rows H (m, n) with noise variances rdiag (m,) (same returns as
    :func:`radical_rt.kernels.updates.gated_update`: status, NIS, 0 accepted / 1 edited).

    Per row: b = P h, α = hᵀb + r, k = b/α with the consider states' entries zeroed (Schmidt
    gain), dx += k (z − h·dx), Joseph form P ← (I − khᵀ)P(I − khᵀ)ᵀ + r kkᵀ, evaluated as
    P − kbᵀ − bkᵀ + α kkᵀ."""
    m, n = H.shape
    nis = dense_innovation_test(P, dx, H, z, rdiag, S, innov, sig, PHt)
    if edit_enabled and not (nis <= gate):
        return 0, nis, 1
    for a in range(m):
        s = 0.0
        for j in range(n):
            s += H[a, j] * dx[j]
        res = z[a] - s
        alpha = rdiag[a]
        for i in range(n):
            acc = 0.0
            for j in range(n):
                acc += P[i, j] * H[a, j]
            b[i] = acc
            alpha += H[a, i] * acc
        if not math.isfinite(alpha):
            return ERR_NONFINITE, nis, 0
        if not (alpha > 0.0 and rdiag[a] > 0.0):
            return ERR_NOT_POSITIVE, nis, 0
        for i in range(n):
            k[i] = 0.0 if consider[i] else b[i] / alpha
            dx[i] += k[i] * res
        for i in range(n):
            for j in range(i, n):
                v = P[i, j] - k[i] * b[j] - b[i] * k[j] + alpha * k[i] * k[j]
                P[i, j] = v
                P[j, i] = v
    for i in range(n):
        if not (P[i, i] > 0.0 and math.isfinite(P[i, i])):
            return ERR_NOT_POSITIVE, nis, 0
    return 0, nis, 0


# -------------------------------------------------------------------------------------- engine
