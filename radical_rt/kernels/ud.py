"""UD-factorized covariance kernels (notes/rimu.md §11): P = U diag(d) Uᵀ — the factorization, the
variances and the measurement updates (the time updates and covariance bumps are in
:mod:`radical_rt.kernels.ud_time`).

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
def has_shape(A, rows, cols):
    """A (2-D) has exactly shape (rows, cols): the shape check of every UD kernel."""
    return A.shape[0] == rows and A.shape[1] == cols


@kernel
def all_finite(A):
    """All entries of the 1-D or 2-D array A are finite."""
    for x in A.flat:
        if not math.isfinite(x):
            return False
    return True


@kernel
def d_status(d):
    """OK if every entry of the diagonal factor d (n,) is positive and finite, else
    ERR_NOT_POSITIVE: the status a kernel returns after updating d in place."""
    for j in range(d.shape[0]):
        if not (d[j] > 0.0 and math.isfinite(d[j])):
            return ERR_NOT_POSITIVE
    return OK


@kernel
def udu_inplace(A, n, dout):
    """The factorization step shared by the UD kernels (status code of :mod:`radical_rt._jit`).
    Factor the upper triangle of A[:n, :n] (SPD) in place: A ← U (strict upper part and unit
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
    if not (has_shape(P, n, n) and has_shape(U, n, n)):
        return ERR_SHAPE
    for i in range(n):
        for j in range(n):
            U[i, j] = P[i, j] if j >= i else 0.0
    return udu_inplace(U, n, d)


@kernel
def ud_to_cov(U, d, P):
    """P (n, n) ← U diag(d) Uᵀ (diagnostics and output only). Bad shapes fill P with NaN."""
    n = d.shape[0]
    if not (has_shape(P, n, n) and has_shape(U, n, n)):
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
    if out.shape[0] != n or not has_shape(U, n, n):
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
    if h.shape[0] != n or f_work.shape[0] < n or not has_shape(U, n, n):
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
    if (not has_shape(U, n, n) or h.shape[0] != n or k_out.shape[0] < n or f_work.shape[0] < n
            or v_work.shape[0] < n):
        return ERR_SHAPE, np.nan
    if not (math.isfinite(r) and all_finite(h)):
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
    if (H.shape[0] != m or not has_shape(R, m, m) or H_out.shape[0] < m or H_out.shape[1] != n
            or z_out.shape[0] < m or L_work.shape[0] < m or L_work.shape[1] < m):
        return ERR_SHAPE
    if not (all_finite(H) and all_finite(R) and all_finite(z)):
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
