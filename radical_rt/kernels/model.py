"""The filter's gyro and parity models and their Jacobians (Numba kernels).

Parameter vector ``xp`` in state order: b (rad/s), λ', μ', du', dv' (the engine's *internal*
linear scaled-axis form, see the section below and docs/engine.md §2), φ2 (rad, body axes), then
the extension state τ (s) — see :mod:`radical_rt.contract.state`. The attitude error ``dtheta`` (body, rad)
is defined in :mod:`radical_rt.contract.conventions`.

Gyro model (CONTRACT §1.5): true axes ``w̃_i = normalize(w_i − du_i v_i − dv_i u_i)``; increments
``y_i = (1 + λ_i + μ_i·sgn(g_i))·g_i + b_i·dt``, ``g_i = w̃_i·θ``. In internal form
``y_i = (1 + μ'_i sgn g_i)·a_iᵀθ + b_i dt`` with the scaled axis ``a_i``; the filter inverts it
with its estimates, ``c_i = (y_i − b̂_i dt)/(1 + μ̂'_i sgn)`` and ``θ̂ = Gp c``,
``Gp = (ÂÂᵀ)⁻¹Â`` over the active gyros.

Error propagation over one sample: ``δθ_k = R(θ̂)ᵀ δθ_{k−1} + F_k δp + w_k`` with
``F_k = ∂θ̂/∂p̂`` (3 × 5n, checked by finite differences). Parity: ``z = Nᵀ c`` with N (n, n−3)
the orthonormal null basis of Â; its measurement row is ``H = −∂z/∂p̂`` (δ = true − estimate).

The star-tracker model is in :mod:`radical_rt.kernels.tracker_model`, the exact conversions
between the internal and the contract's parameters in :mod:`radical_rt.kernels.parametrization`,
the attitude step (:func:`radical_rt.kernels.rotation.apply_body_rotation`) with the rotation kernels.
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt._jit import inline_kernel, kernel
from radical_rt.kernels.rotation import apply_body_rotation


@kernel
def inv3(M, out):
    """Inverse of a 3×3 matrix M into out (adjugate / determinant); returns det M. out is written
    only when det M ≠ 0 (and is then finite when M is)."""
    c00 = M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1]
    c01 = M[1, 2] * M[2, 0] - M[1, 0] * M[2, 2]
    c02 = M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0]
    det = M[0, 0] * c00 + M[0, 1] * c01 + M[0, 2] * c02
    if det == 0.0 or not math.isfinite(det):
        return det
    r = 1.0 / det
    out[0, 0], out[1, 0], out[2, 0] = c00 * r, c01 * r, c02 * r
    out[0, 1] = (M[0, 2] * M[2, 1] - M[0, 1] * M[2, 2]) * r
    out[1, 1] = (M[0, 0] * M[2, 2] - M[0, 2] * M[2, 0]) * r
    out[2, 1] = (M[0, 1] * M[2, 0] - M[0, 0] * M[2, 1]) * r
    out[0, 2] = (M[0, 1] * M[1, 2] - M[0, 2] * M[1, 1]) * r
    out[1, 2] = (M[0, 2] * M[1, 0] - M[0, 0] * M[1, 2]) * r
    out[2, 2] = (M[0, 0] * M[1, 1] - M[0, 1] * M[1, 0]) * r
    return det


@kernel
def masked_pinv(Wt, active, Minv_out, Gp_out):
    """Pseudo-inverse over the active gyros only: Gp (3, n) with zero columns for inactive ones.

    active (n,) bool. Returns the number of active gyros, or −1 if they do not span body space.
    """
    n = Wt.shape[1]
    M = np.zeros((3, 3))
    na = 0
    for i in range(n):
        if active[i]:
            na += 1
            for r in range(3):
                for c in range(3):
                    M[r, c] += Wt[r, i] * Wt[c, i]
    if na < 3 or abs(inv3(M, Minv_out)) < 1e-9:
        return -1
    for i in range(n):
        for r in range(3):
            s = 0.0
            if active[i]:
                for c in range(3):
                    s += Minv_out[r, c] * Wt[c, i]
            Gp_out[r, i] = s
    return na


# ---------------------------------------------------------------------------------------------
# Internal (linear) parametrization used by the engine.
#
# The contract's parameters (λ, μ, du, dv) enter the increment model nonlinearly through the
# normalized axis w̃(du, dv) and the product (1 + λ)·w̃. With x and z rotations only, one direction
# per gyro (the y component of the scaled axis) is unobservable; in the contract coordinates that
# unobservable set is a *curved* line, so an EKF linearized at moving estimates gains spurious
# information along it and drifts (docs/engine.md). The engine therefore estimates, per gyro, the
# scaled sense axis a_i = (1 + λ̂'_i) w_i − dû'_i v_i − dv̂'_i u_i, which is *linear* in the
# internal parameters (λ', du', dv'), and μ' = μ/(1 + λ):
#     y_i = (1 + μ'_i sgn g_i)·a_iᵀθ + b_i dt      (exactly the contract's model)
# so the increment model is linear in (λ', du', dv') for a given θ and every unobservable set is
# a straight line. Conversions to and from the contract's parameters are exact
# (:mod:`radical_rt.kernels.parametrization`).
# ---------------------------------------------------------------------------------------------


@kernel
def refresh_axes(xp, W, U_ax, V_ax, N_ref, A, Minv, Gp, N):
    """Rebuild the estimated scaled axes A and everything derived from them (internal params).

    xp (5n+3,) internal parameters; W, U_ax, V_ax (3, n) nominal triads; N_ref (n, n−3) previous
    parity basis (for continuity; it may be N itself). Writes A (3, n) with columns
    a_i = (1+λ'_i) w_i − du'_i v_i − dv'_i u_i, Minv (3, 3) = (A Aᵀ)⁻¹, Gp (3, n) = Minv A, N (n, n−3) orthonormal basis of null(A).
    Returns 0, or 1 if A Aᵀ is singular.
    """
    n = W.shape[1]
    for i in range(n):
        sl = 1.0 + xp[n + i]
        du = xp[3 * n + i]
        dv = xp[4 * n + i]
        for r in range(3):
            A[r, i] = sl * W[r, i] - du * V_ax[r, i] - dv * U_ax[r, i]
    M = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            s = 0.0
            for i in range(n):
                s += A[r, i] * A[c, i]
            M[r, c] = s
    Mi = np.empty((3, 3))
    if abs(inv3(M, Mi)) < 1e-12:
        return 1
    Minv[:, :] = Mi
    for r in range(3):
        for i in range(n):
            Gp[r, i] = Minv[r, 0] * A[0, i] + Minv[r, 1] * A[1, i] + Minv[r, 2] * A[2, i]
    # B = (I − AᵀGp) N_ref = N_ref − Aᵀ(Gp N_ref): the previous basis projected on null(A)
    m = N_ref.shape[1]
    y = np.empty((3, m))
    for r in range(3):
        for c in range(m):
            s = 0.0
            for k in range(n):
                s += Gp[r, k] * N_ref[k, c]
            y[r, c] = s
    B = np.empty((n, m))
    for k in range(n):
        for c in range(m):
            B[k, c] = N_ref[k, c] - (A[0, k] * y[0, c] + A[1, k] * y[1, c] + A[2, k] * y[2, c])
    for c in range(B.shape[1]):
        for k in range(c):
            s = 0.0
            for r in range(n):
                s += B[r, c] * B[r, k]
            for r in range(n):
                B[r, c] -= s * B[r, k]
        s = 0.0
        for r in range(n):
            s += B[r, c] * B[r, c]
        s = math.sqrt(s)
        for r in range(n):
            B[r, c] /= s
    N[:, :] = B
    return 0


@kernel
def fold_correction(dx, q, xp, W, U_ax, V_ax, A, Minv, Gp, N):
    """Fold the error-state correction dx (ns,) into the estimate, then dx ← 0: the attitude
    q_body_from_inertial (4,) ← R(δθ)ᵀ ∘ q with δθ = dx[:3] (body, rad; normalized, w ≥ 0), the
    parameters xp ← xp + dx[3:], and the geometry of :func:`refresh_axes` (A, Minv, Gp, N, with
    the previous N as its continuity reference) rebuilt from the new xp.
    Returns −1 if dx is all zero (nothing changed), 0, or 1 if A Aᵀ became singular.
    """
    nz = False
    for k in range(dx.shape[0]):
        if dx[k] != 0.0:
            nz = True
            break
    if not nz:
        return -1
    apply_body_rotation(q, dx[:3], np.empty(4), np.empty(4))
    for k in range(xp.shape[0]):
        xp[k] += dx[3 + k]
    dx[:] = 0.0
    return refresh_axes(xp, W, U_ax, V_ax, N, A, Minv, Gp, N)


@inline_kernel
def correct_increment_lin(y, dt, xp, active, c_out, sgn_out, s_out):
    """Corrected increments c_i = (y_i − b̂_i dt)/(1 + μ̂'_i sgn) ≈ a_iᵀθ (internal params).

    Writes c_out, sgn_out (sign of y − b̂·dt) and s_out (1 + μ̂'·sgn); zero / one for inactive gyros.
    """
    n = y.shape[0]
    for i in range(n):
        if not active[i]:
            c_out[i] = 0.0
            sgn_out[i] = 0.0
            s_out[i] = 1.0
            continue
        e = y[i] - xp[i] * dt
        sg = 1.0 if e >= 0.0 else -1.0
        s = 1.0 + xp[2 * n + i] * sg
        c_out[i] = e / s
        sgn_out[i] = sg
        s_out[i] = s


@kernel
def increment_jacobian_lin(g, sgn, s, dt, theta, W, U_ax, V_ax, Gp, active, F):
    """F (3, 5n) = ∂theta_hat/∂p̂ in the internal parametrization (b, λ', μ', du', dv').

    theta_hat = Gp c with Gp = (AAᵀ)⁻¹A. g (n,) = Aᵀ theta_hat (the corrected increments without
    their parity-direction noise, used in the μ' column); sgn, s from
    :func:`correct_increment_lin`. The λ', du', dv' columns are −Gp[:, i]·(∂a_i/∂p)ᵀθ̂ with the
    *nominal* constant vectors w_i, −v_i, −u_i. Exact derivative for noise-free data. Column
    group k (0..4) of gyro i is column k·n + i (:func:`jacobian_gyro` computes one gyro's five).
    """
    n = g.shape[0]
    Fi = np.empty((3, 5))
    for i in range(n):
        jacobian_gyro(i, g, sgn, s, dt, theta, W, U_ax, V_ax, Gp, active, Fi)
        for r in range(3):
            for k in range(5):
                F[r, k * n + i] = Fi[r, k]


@inline_kernel
def jacobian_gyro(i, g, sgn, s, dt, theta, W, U_ax, V_ax, Gp, active, Fi):
    """The five columns of gyro i in :func:`increment_jacobian_lin` (same arguments) into Fi
    (3, 5): ∂theta_hat/∂(b_i, λ'_i, μ'_i, du'_i, dv'_i); zero for an inactive gyro."""
    if not active[i]:
        for r in range(3):
            for k in range(5):
                Fi[r, k] = 0.0
        return
    wt = W[0, i] * theta[0] + W[1, i] * theta[1] + W[2, i] * theta[2]
    vt = V_ax[0, i] * theta[0] + V_ax[1, i] * theta[1] + V_ax[2, i] * theta[2]
    ut = U_ax[0, i] * theta[0] + U_ax[1, i] * theta[1] + U_ax[2, i] * theta[2]
    for r in range(3):
        gp = Gp[r, i]
        Fi[r, 0] = -gp * dt / s[i]
        Fi[r, 1] = -gp * wt
        Fi[r, 2] = -gp * sgn[i] * g[i] / s[i]
        Fi[r, 3] = gp * vt
        Fi[r, 4] = gp * ut


@kernel
def parity_rows_lin(c, g, sgn, s, dt, theta, N, W, U_ax, V_ax, z_acc, H_acc):
    """Accumulate z = Nᵀc (n−3,) and its rows H = −∂z/∂p̂ (n−3, ≥5n), internal parametrization.

    N (n, n−3) orthonormal basis of null(A); g (n,) = Aᵀθ̂ replaces c in the μ' column (no
    parity-noise in H). Columns b, λ', μ', du', dv'.
    """
    n = c.shape[0]
    for i in range(n):
        wt = W[0, i] * theta[0] + W[1, i] * theta[1] + W[2, i] * theta[2]
        vt = V_ax[0, i] * theta[0] + V_ax[1, i] * theta[1] + V_ax[2, i] * theta[2]
        ut = U_ax[0, i] * theta[0] + U_ax[1, i] * theta[1] + U_ax[2, i] * theta[2]
        for r in range(N.shape[1]):
            p = N[i, r]
            z_acc[r] += p * c[i]
            H_acc[r, i] += p * dt / s[i]
            H_acc[r, n + i] += p * wt
            H_acc[r, 2 * n + i] += p * sgn[i] * g[i] / s[i]
            H_acc[r, 3 * n + i] -= p * vt
            H_acc[r, 4 * n + i] -= p * ut


@kernel
def parity_from_stats(par_y, par_t, xp, A, Gp, N, W, U_ax, V_ax, z_out, H_out, theta_out, Phi_out):
    """Parity measurement of a sum of samples, recomputed exactly from its sufficient statistics.

    par_y (2, n): per gyro, the sums of the raw increments y [rad] of the samples whose corrected
    sign was + (row 0) or − (row 1); par_t (2, n): the matching sums of the sample intervals [s].
    With the *current* internal parameters xp (and A, Gp = (AAᵀ)⁻¹A, N = null basis of A): the
    corrected sums C_i = Σ± (Y±_i − b̂_i T±_i)/(1 ± μ̂'_i), the parity z = NᵀC (n−3,), the summed
    body increment Θ = Gp C (3,), the rows H = −∂z/∂p̂ (n−3, ≥5n; columns b, λ', μ', du', dv'; the
    λ', du', dv' columns use Θ, the μ' column the part of C in the range of Aᵀ) and Phi_out
    (3, 5n) = ∂Θ/∂p̂ (the sensitivity of the regressor Θ to the parameter errors).
    Because the statistics are sums of raw data, the measurement can be formed at any later time,
    linearized about the estimate of that time (see docs/engine.md).
    """
    n = par_y.shape[1]
    cp = np.empty(n)
    cm = np.empty(n)
    c = np.empty(n)
    for i in range(n):
        mu = xp[2 * n + i]
        cp[i] = (par_y[0, i] - xp[i] * par_t[0, i]) / (1.0 + mu)
        cm[i] = (par_y[1, i] - xp[i] * par_t[1, i]) / (1.0 - mu)
        c[i] = cp[i] + cm[i]
    for r in range(3):
        s = 0.0
        for i in range(n):
            s += Gp[r, i] * c[i]
        theta_out[r] = s
    for j in range(H_out.shape[0]):
        for col in range(H_out.shape[1]):
            H_out[j, col] = 0.0
    for i in range(n):
        mu = xp[2 * n + i]
        tb = par_t[0, i] / (1.0 + mu) + par_t[1, i] / (1.0 - mu)
        smu = cp[i] / (1.0 + mu) - cm[i] / (1.0 - mu)  # Σ sgn·c/(1 + μ sgn)
        g = A[0, i] * theta_out[0] + A[1, i] * theta_out[1] + A[2, i] * theta_out[2]
        if c[i] != 0.0:
            smu *= g / c[i]  # the same, without the parity-direction noise of c
        wt = W[0, i] * theta_out[0] + W[1, i] * theta_out[1] + W[2, i] * theta_out[2]
        vt = V_ax[0, i] * theta_out[0] + V_ax[1, i] * theta_out[1] + V_ax[2, i] * theta_out[2]
        ut = U_ax[0, i] * theta_out[0] + U_ax[1, i] * theta_out[1] + U_ax[2, i] * theta_out[2]
        for r in range(3):
            gp = Gp[r, i]
            Phi_out[r, i] = -gp * tb
            Phi_out[r, n + i] = -gp * wt
            Phi_out[r, 2 * n + i] = -gp * smu
            Phi_out[r, 3 * n + i] = gp * vt
            Phi_out[r, 4 * n + i] = gp * ut
        for j in range(N.shape[1]):
            p = N[i, j]
            H_out[j, i] = p * tb
            H_out[j, n + i] = p * wt
            H_out[j, 2 * n + i] = p * smu
            H_out[j, 3 * n + i] = -p * vt
            H_out[j, 4 * n + i] = -p * ut
    for j in range(N.shape[1]):
        s = 0.0
        for i in range(n):
            s += N[i, j] * c[i]
        z_out[j] = s
