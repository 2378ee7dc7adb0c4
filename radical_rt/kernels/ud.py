"""UD-factorized covariance kernels (notes/rimu.md §11): P = U diag(d) Uᵀ.

U is a full (n, n) float64 array, unit upper triangular (ones on the diagonal, zeros below), and
d is (n,) with d > 0. Every kernel works in place, allocates nothing (the caller passes the work
arrays; :class:`UDWorkspace` preallocates all of them), never raises, and returns a status code
from :mod:`radical_rt._jit` (OK, ERR_NOT_POSITIVE, ERR_SHAPE, ERR_NONFINITE). Unless a docstring
says otherwise, a kernel that returns an error leaves U and d unchanged. Units are those of the
state (SI); covariances are in state units squared.

References (notes §1.2): G. J. Bierman, *Factorization Methods for Discrete Sequential
Estimation*, Academic Press, 1977 (Bierman 1977); C. L. Thornton and G. J. Bierman, "UDUᵀ
covariance factorization for Kalman filtering", in *Control and Dynamic Systems* vol. 16
(C. T. Leondes, ed.), Academic Press, 1980 (Thornton & Bierman 1980); W. S. Agee and
R. H. Turner, "Triangular decomposition of a positive definite matrix plus a symmetric dyad, with
application to Kalman filtering", White Sands Missile Range TR-38, 1972 (Agee & Turner 1972).
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt._jit import ERR_NONFINITE, ERR_NOT_POSITIVE, ERR_SHAPE, OK, kernel
from radical_rt.kernels.ud_workspace import UDWorkspace as UDWorkspace  # re-export


@kernel
def _is(A, rows, cols):
    """A has exactly shape (rows, cols)."""
    return A.shape[0] == rows and A.shape[1] == cols


@kernel
def _finite(A):
    """All entries of the 1-D or 2-D array A are finite."""
    for x in A.flat:
        if not math.isfinite(x):
            return False
    return True


@kernel
def _d_ok(d):
    for j in range(d.shape[0]):
        if not (d[j] > 0.0 and math.isfinite(d[j])):
            return ERR_NOT_POSITIVE
    return OK


@kernel
def _udu_inplace(A, n, dout):
    """Factor the upper triangle of A[:n, :n] (SPD) in place: A ← U (strict upper part and unit
    diagonal; the strict lower part is not touched), dout[:n] ← d (Bierman 1977, §11.1)."""
    for j in range(n - 1, -1, -1):
        dj = A[j, j]
        if not (dj > 0.0 and math.isfinite(dj)):
            return ERR_NOT_POSITIVE
        dout[j] = dj
        for i in range(j):
            A[i, j] /= dj
        for i in range(j):
            t = dj * A[i, j]
            for k in range(i, j):
                A[i, k] -= t * A[k, j]
        A[j, j] = 1.0
    return OK


@kernel
def factor_ud(P, U, d):
    """UD factors of an SPD P (n, n) into U (n, n) and d (n,) (Bierman 1977, §11.1).

    Only the upper triangle of P is read and P is not modified. On ERR_NOT_POSITIVE (a pivot ≤ 0 or
    non-finite) the contents of U and d are unspecified: factor into scratch arrays if the old
    factors must survive a failure.
    """
    n = d.shape[0]
    if not (_is(P, n, n) and _is(U, n, n)):
        return ERR_SHAPE
    for i in range(n):
        for j in range(n):
            U[i, j] = P[i, j] if j >= i else 0.0
    return _udu_inplace(U, n, d)


@kernel
def ud_to_cov(U, d, P):
    """P (n, n) ← U diag(d) Uᵀ (diagnostics and output only). Bad shapes fill P with NaN."""
    n = d.shape[0]
    if not (_is(P, n, n) and _is(U, n, n)):
        P[:] = np.nan
        return
    for i in range(n):
        for k in range(i, n):
            s = 0.0
            for j in range(k, n):
                s += U[i, j] * d[j] * U[k, j]
            P[i, k] = s
            P[k, i] = s


@kernel
def variances(U, d, out):
    """out[i] ← P_ii = Σ_{j≥i} U_ij² d_j for U (n, n), d (n,), out (n,); O(n²), P not formed."""
    n = d.shape[0]
    if out.shape[0] != n or not _is(U, n, n):
        out[:] = np.nan
        return
    for i in range(n):
        s = d[i]
        for j in range(i + 1, n):
            s += U[i, j] * U[i, j] * d[j]
        out[i] = s


@kernel
def variances_within(U, d, out, limit, start):
    """:func:`variances` into out (n,), then True if out[start + i] ≤ limit[i] for every i of
    limit (n − start,) (False on a NaN): the convergence test on the UD variances."""
    variances(U, d, out)
    for i in range(limit.shape[0]):
        if not (out[start + i] <= limit[i]):
            return False
    return True


@kernel
def ut_times(U, h, f, n):
    """f[:n] ← Uᵀh for unit upper U, skipping zero entries of h (sparse star-tracker rows)."""
    f[:n] = 0.0
    for i in range(n):
        hi = h[i]
        if hi != 0.0:
            f[i] += hi
            for j in range(i + 1, n):
                f[j] += U[i, j] * hi


@kernel
def innovation_variance(U, d, h, r, f_work):
    """α = h P hᵀ + r for a row h (n,), noise variance r; f_work (n,) ← Uᵀh. NaN on bad shapes."""
    n = d.shape[0]
    if h.shape[0] != n or f_work.shape[0] < n or not _is(U, n, n):
        return np.nan
    ut_times(U, h, f_work, n)
    alpha = r
    for j in range(n):
        alpha += d[j] * f_work[j] * f_work[j]
    return alpha


@kernel
def bierman_update(U, d, h, r, k_out, f_work, v_work):
    """Scalar measurement update z = h x + v, var(v) = r > 0, in place (Bierman 1977, §11.2).

    U (n, n), d (n,), h (n,), work f_work, v_work (n,). Writes the Kalman gain K = P hᵀ/α into
    k_out (n,) and returns (status, α) with α = h P hᵀ + r the innovation variance (prior P). The
    caller applies dx += K (z − h·dx). Input errors (shapes, non-finite h or r, r ≤ 0, α not
    positive) change nothing; ERR_NOT_POSITIVE after the update (a d_j underflowed) leaves the
    updated factors in place for the caller to flag and recover.
    """
    n = d.shape[0]
    if (not _is(U, n, n) or h.shape[0] != n or k_out.shape[0] < n or f_work.shape[0] < n
            or v_work.shape[0] < n):
        return ERR_SHAPE, np.nan
    if not (math.isfinite(r) and _finite(h)):
        return ERR_NONFINITE, np.nan
    if not r > 0.0:
        return ERR_NOT_POSITIVE, np.nan
    ut_times(U, h, f_work, n)
    a_tot = r
    for j in range(n):
        v_work[j] = d[j] * f_work[j]
        a_tot += v_work[j] * f_work[j]
        k_out[j] = v_work[j]  # k_out accumulates the unnormalized gain b
    if not math.isfinite(a_tot):
        return ERR_NONFINITE, a_tot
    if not a_tot > 0.0:
        return ERR_NOT_POSITIVE, a_tot
    alpha = r
    gamma = 1.0 / alpha
    for j in range(n):
        fj = f_work[j]
        if fj == 0.0:
            continue  # an identity step (b_j = 0, λ = 0): skip it exactly
        beta = alpha
        alpha += v_work[j] * fj
        lam = -fj * gamma
        gamma = 1.0 / alpha
        d[j] *= beta * gamma
        bj = k_out[j]
        for i in range(j):
            t = U[i, j]
            U[i, j] = t + k_out[i] * lam
            k_out[i] += bj * t
    for i in range(n):
        k_out[i] *= gamma
    for j in range(n):
        if not (d[j] > 0.0 and math.isfinite(d[j])):
            return ERR_NOT_POSITIVE, alpha
    return OK, alpha


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
    if (not (_is(U, n, n) and _is(Phi, n, n) and _is(G, n, r)) or Y_work.shape[0] < n
            or Y_work.shape[1] < w or Dw_work.shape[0] < w or c_work.shape[0] < w):
        return ERR_SHAPE
    if not (_finite(Phi) and _finite(G) and _finite(q)):
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
    if (m < 1 or m > n or not (_is(U, n, n) and _is(Phi_aa, m, m) and _is(Phi_ap, m, p)
                                and _is(Q_aa, m, m)) or work.shape[0] < m or work.shape[1] < n + m):
        return ERR_SHAPE
    if not (_finite(Phi_aa) and _finite(Phi_ap) and _finite(Q_aa)):
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
    status = _udu_inplace(work[:m, n:n + m], m, dcol)
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
    if not _is(U, n, n) or a.shape[0] != n or a_work.shape[0] < n:
        return ERR_SHAPE
    if not (math.isfinite(c) and _finite(a)):
        return ERR_NONFINITE
    if c < 0.0:
        return ERR_NOT_POSITIVE
    if c == 0.0 or n == 0:
        return OK
    for i in range(n):
        a_work[i] = a[i]
    _agee_turner_core(U, d, c, a_work, n - 1)
    return _d_ok(d)


@kernel
def add_diagonal_noise(U, d, idx, c, a_work):
    """P[idx[k], idx[k]] += c[k] for each k, by Agee-Turner with a = e_idx[k] (§11.7): only columns
    ≤ idx[k] are touched (≈ idx[k]² flops each). idx (K,) int, c (K,) ≥ 0, a_work (n,).
    Used for random-walk parameter process noise (c = q Δt) and additive covariance bumps.
    """
    n = d.shape[0]
    K = idx.shape[0]
    if not _is(U, n, n) or c.shape[0] != K or a_work.shape[0] < n:
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
    return _d_ok(d)


@kernel
def reset_leading_block(U, d, m, P0, work):
    """Warm-start reset (§11.6): U[:m, m:] ← 0 (no attitude-parameter cross-covariance) and the
    leading block ← UD factors of P0 (m, m) SPD. U[m:, m:] and d[m:] are not touched (bit-for-bit).
    work: (≥ m, ≥ m + 1), e.g. :func:`structured_work`. Transactional.
    """
    n = d.shape[0]
    if m < 1 or m > n or not (_is(U, n, n) and _is(P0, m, m)) or work.shape[0] < m \
            or work.shape[1] < m + 1:
        return ERR_SHAPE
    if not _finite(P0):
        return ERR_NONFINITE
    for i in range(m):
        for j in range(m):
            work[i, j] = P0[i, j] if j >= i else 0.0
    dcol = work[:, m]
    status = _udu_inplace(work[:m, :m], m, dcol)
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
    if not _is(U, n, n) or s.shape[0] != n:
        return ERR_SHAPE
    if not _finite(s):
        return ERR_NONFINITE
    for i in range(n):
        if not s[i] > 0.0:
            return ERR_NOT_POSITIVE
    for j in range(n):
        for i in range(j):
            U[i, j] = s[i] * U[i, j] / s[j]
        d[j] *= s[j] * s[j]
    return _d_ok(d)


@kernel
def cholesky_lower(R, m, L):
    """Lower Cholesky factor L[:m, :m] (strict upper part not written) of the symmetric positive
    definite R[:m, :m] (lower triangle read). Returns OK, or ERR_NOT_POSITIVE at a pivot ≤ 0."""
    for j in range(m):
        s = R[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return ERR_NOT_POSITIVE
        L[j, j] = math.sqrt(s)
        for i in range(j + 1, m):
            t = R[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / L[j, j]
    return OK


@kernel
def decorrelate(H, z, R, H_out, z_out, L_work):
    """Whitening of z = H x + v, cov(v) = R (§11.3; Bierman 1977 ch. V): R = L Lᵀ (L lower,
    in L_work (≥ m, ≥ m)), H_out[:m] ← L⁻¹H, z_out[:m] ← L⁻¹z, so each row is a scalar update with
    r = 1. H (m, n), z (m,), R (m, m) SPD (lower triangle read). H_out/z_out may alias H/z.
    """
    m = z.shape[0]
    n = H.shape[1]
    if (H.shape[0] != m or not _is(R, m, m) or H_out.shape[0] < m or H_out.shape[1] != n
            or z_out.shape[0] < m or L_work.shape[0] < m or L_work.shape[1] < m):
        return ERR_SHAPE
    if not (_finite(H) and _finite(R) and _finite(z)):
        return ERR_NONFINITE
    L = L_work
    if cholesky_lower(R, m, L) != OK:
        return ERR_NOT_POSITIVE
    for i in range(m):  # forward substitution, row by row (alias-safe)
        for col in range(n):
            t = H[i, col]
            for k in range(i):
                t -= L[i, k] * H_out[k, col]
            H_out[i, col] = t / L[i, i]
        t = z[i]
        for k in range(i):
            t -= L[i, k] * z_out[k]
        z_out[i] = t / L[i, i]
    return OK
