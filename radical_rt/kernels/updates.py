"""Gated vector measurement update on UD factors (one Numba call per tracker or parity update).

For m measurement rows with diagonal noise: the innovation covariance S = H P Hᵀ + R is formed from
the UD factors (F = H U, S = F D Fᵀ + R; P itself is never formed), the normalized innovation
squared NIS = νᵀS⁻¹ν is tested against the gate, and if accepted the rows are applied as m
sequential scalar Bierman updates, each with the innovation recomputed from the updated correction
dx (error-state form, notes §11.3).
"""

from __future__ import annotations

import numpy as np

from radical_rt._jit import kernel
from radical_rt.kernels.ud import bierman_update, cholesky_lower, ut_times
from radical_rt.kernels.ud_time import agee_turner

UPDATE_ACCEPTED = 0
UPDATE_EDITED = 1


@kernel
def innovation_test(U, d, dx, H, z, rdiag, F, S, innov, sig):
    """Innovations innov = z − H dx, S = H P Hᵀ + R from the UD factors (F = Uᵀhᵀ rows; P never
    formed), sig = sqrt(diag S); returns the NIS νᵀS⁻¹ν. Shapes as in :func:`gated_update`."""
    m, n = H.shape
    for a in range(m):
        s = 0.0
        for j in range(n):
            s += H[a, j] * dx[j]
        innov[a] = z[a] - s
        ut_times(U, H[a], F[a], n)  # F[a] = Uᵀ h_a (U unit upper triangular; zeros of h skipped)
    for a in range(m):
        for b in range(m):
            acc = rdiag[a] if a == b else 0.0
            for j in range(n):
                acc += F[a, j] * d[j] * F[b, j]
            S[a, b] = acc
        sig[a] = np.sqrt(S[a, a]) if S[a, a] > 0 else 0.0
    return spd_quadratic(S, innov)


@kernel
def spd_quadratic(S, v):
    """vᵀS⁻¹v for S (m, m) symmetric positive definite and v (m,), by a Cholesky factorization
    S = LLᵀ (lower triangle of S read): |L⁻¹v|². NaN if S is not positive definite (a gated
    update then edits the measurement)."""
    m = v.shape[0]
    L = np.zeros((m, m))
    if cholesky_lower(S, m, L) != 0:
        return np.nan
    out = 0.0
    y = np.empty(m)
    for j in range(m):  # y = L⁻¹v
        t = v[j]
        for k in range(j):
            t -= L[j, k] * y[k]
        y[j] = t / L[j, j]
        out += y[j] * y[j]
    return out


@kernel
def gated_update(U, d, dx, H, z, rdiag, gate, edit_enabled, F, S, innov, sig, f, v, k):
    """Apply rows H (m, n) with measurements z (m,) and noise variances rdiag (m,) to (U, d, dx).

    Writes innov (m,) = z − H dx (before the update) and sig (m,) = sqrt(diag S).
    Returns (kernel status, NIS, UPDATE_ACCEPTED or UPDATE_EDITED).
    """
    m, n = H.shape
    nis = innovation_test(U, d, dx, H, z, rdiag, F, S, innov, sig)
    if edit_enabled and not (nis <= gate):
        return 0, nis, UPDATE_EDITED
    for a in range(m):
        s = 0.0
        for j in range(n):
            s += H[a, j] * dx[j]
        res = z[a] - s
        status, _alpha = bierman_update(U, d, H[a], rdiag[a], k, f, v)
        if status != 0:
            return status, nis, UPDATE_ACCEPTED
        for j in range(n):
            dx[j] += k[j] * res
    return 0, nis, UPDATE_ACCEPTED


@kernel
def gated_update_consider(U, d, dx, H, z, rdiag, gate, edit_enabled, consider, F, S, innov, sig, f,
                          v, k, a):
    """:func:`gated_update` with some states treated as Schmidt *consider* states.

    consider (n,) bool: those states are not corrected and their covariance block is kept at its
    prior value, while the other states and the cross-covariances get the ordinary (optimal for the
    solve-for states) update. Per scalar row: the ordinary Bierman update, then the consider
    block's share K_c α K_cᵀ is added back by an Agee-Turner rank-one update with a = K masked to
    the consider states (notes §11.8; exact). a (n,) work. Same returns as :func:`gated_update`.
    """
    m, n = H.shape
    nis = innovation_test(U, d, dx, H, z, rdiag, F, S, innov, sig)
    if edit_enabled and not (nis <= gate):
        return 0, nis, UPDATE_EDITED
    kc = np.zeros(n)
    for r in range(m):
        s = 0.0
        for j in range(n):
            s += H[r, j] * dx[j]
        res = z[r] - s
        status, alpha = bierman_update(U, d, H[r], rdiag[r], k, f, v)
        if status != 0:
            return status, nis, UPDATE_ACCEPTED
        for j in range(n):
            if consider[j]:
                kc[j] = k[j]
            else:
                kc[j] = 0.0
                dx[j] += k[j] * res
        status = agee_turner(U, d, alpha, kc, a)
        if status != 0:
            return status, nis, UPDATE_ACCEPTED
    return 0, nis, UPDATE_ACCEPTED


@kernel
def timing_noise(R_nom, omega, rdiag, sig_t, R_out):
    """Tracker noise covariance with the time-line term: R_out (3, 3) ← diag(rdiag) + σ_t² v vᵀ,
    v = R_nom ω̂ (the attitude error per second of epoch error in tracker axes [rad/s]); R_nom
    (3, 3) R_st_from_body, omega (3,) [rad/s], rdiag (3,) [rad²], sig_t [s]."""
    v = np.empty(3)
    for r in range(3):
        v[r] = R_nom[r, 0] * omega[0] + R_nom[r, 1] * omega[1] + R_nom[r, 2] * omega[2]
    s2 = sig_t * sig_t
    for a in range(3):
        for b in range(3):
            R_out[a, b] = (rdiag[a] if a == b else 0.0) + s2 * (v[a] * v[b])


@kernel
def unwhiten_diagnostics(L, innov_w, S_w, innov_out, sig_out):
    """Innovation and its 1σ of a whitened update back in physical units: innov_out ← L innov_w,
    sig_out ← sqrt(max(diag(L S_w Lᵀ), 0)); L (m, m) lower Cholesky factor of R, S_w (m, m)."""
    m = innov_w.shape[0]
    for a in range(m):
        s = 0.0
        for b in range(a + 1):
            s += L[a, b] * innov_w[b]
        innov_out[a] = s
    for a in range(m):
        s = 0.0
        for b in range(a + 1):
            t = 0.0
            for c in range(a + 1):
                t += L[a, c] * S_w[c, b]
            s += t * L[a, b]
        sig_out[a] = np.sqrt(s) if s > 0.0 else 0.0
