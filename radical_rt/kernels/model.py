"""The filter's gyro, parity and star-tracker models and their Jacobians (Numba kernels).

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
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt._jit import inline_kernel, kernel
from radical_rt.kernels.rotation import (
    dcm_to_quat,
    quat_mul_into,
    quat_normalize_inplace,
    quat_to_dcm,
    quat_to_dcm_into,
    rotvec_to_dcm,
    rotvec_to_quat_into,
)


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


@kernel
def apply_body_rotation(q, theta, work4, dq):
    """q_body_from_inertial ← R(theta)ᵀ ∘ q: the body turned by theta (3,) [rad, body axes]."""
    rotvec_to_quat_into(theta, dq)
    apply_body_quat(q, dq, work4)


@kernel
def apply_body_quat(q, dq, work4):
    """:func:`apply_body_rotation` with the quaternion dq (4,) of R(theta) already computed (dq
    is conjugated in place); work4 (4,) work."""
    dq[0], dq[1], dq[2] = -dq[0], -dq[1], -dq[2]
    quat_mul_into(dq, q, work4)
    for k in range(4):
        q[k] = work4[k]
    quat_normalize_inplace(q)


@kernel
def left_jacobian(phi):
    """SO(3) left Jacobian J_l(phi) (3, 3): exp([(phi+δ)×]) ≈ exp([J_l δ ×]) exp([phi×])."""
    a = math.sqrt(phi[0] ** 2 + phi[1] ** 2 + phi[2] ** 2)
    K = np.zeros((3, 3))
    K[0, 1], K[0, 2], K[1, 0] = -phi[2], phi[1], phi[2]
    K[1, 2], K[2, 0], K[2, 1] = -phi[0], -phi[1], phi[0]
    c1, c2 = (0.5, 0.0) if a < 1e-8 else ((1.0 - math.cos(a)) / (a * a), (a - math.sin(a)) / (a ** 3))
    J = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            kk = K[r, 0] * K[0, c] + K[r, 1] * K[1, c] + K[r, 2] * K[2, c]
            J[r, c] = (1.0 if r == c else 0.0) + c1 * K[r, c] + c2 * kk
    return J


@kernel
def tracker_residual(q_meas, q_body_est, R_st_from_body_nom, phi, use_phi, r_out, H_att, H_phi):
    """Residual r (3,) [rad, tracker axes] and Jacobians of a star-tracker measurement.

    q_meas (4,) = measured q_st_from_inertial; q_body_est (4,) = q_body_from_inertial at the epoch;
    R_st_from_body_nom (3, 3); phi (3,) the tracker's misalignment estimate (body axes), used when
    use_phi. Model: R_st_from_inertial = R_nom R(phi)ᵀ R_body_from_inertial; residual
    r = −rotvec(R_meas R̂ᵀ) = R_nom R(φ̂)ᵀ (δθ + J_l(φ̂) δφ) to first order, so
    H_att = R_nom R(φ̂)ᵀ and H_phi = H_att J_l(φ̂) (zero if not use_phi).
    """
    tracker_geometry(R_st_from_body_nom, phi, use_phi, H_att, H_phi)
    tracker_error(q_meas, q_body_est, H_att, r_out)


@kernel
def tracker_geometry(R_st_from_body_nom, phi, use_phi, H_att, H_phi):
    """The rows of :func:`tracker_residual`, which do not depend on the attitude: H_att (3, 3) =
    R_nom R(φ̂)ᵀ and H_phi (3, 3) = H_att J_l(φ̂), zero if not use_phi (φ̂ (3,) [rad, body])."""
    if use_phi:
        q_phi = np.empty(4)
        Rphi = np.empty((3, 3))
        rotvec_to_quat_into(phi, q_phi)
        quat_to_dcm_into(q_phi, Rphi)
        for r in range(3):  # H_att = R_nom R(φ̂)ᵀ
            for c in range(3):
                H_att[r, c] = (R_st_from_body_nom[r, 0] * Rphi[c, 0] + R_st_from_body_nom[r, 1]
                               * Rphi[c, 1] + R_st_from_body_nom[r, 2] * Rphi[c, 2])
        J = left_jacobian(phi)
        for r in range(3):
            for c in range(3):
                H_phi[r, c] = H_att[r, 0] * J[0, c] + H_att[r, 1] * J[1, c] + H_att[r, 2] * J[2, c]
    else:
        H_att[:, :] = R_st_from_body_nom
        H_phi[:, :] = 0.0


@kernel
def tracker_error(q_meas, q_body_est, H_att, r_out):
    """The residual of :func:`tracker_residual` given its H_att (3, 3) (:func:`tracker_geometry`):
    r_out (3,) = −rotvec(R_meas (H_att R̂_body)ᵀ) [rad, tracker axes], exact below π."""
    w = np.empty((4, 3, 3))  # R_meas, R̂_body, H_att R̂_body, E
    Rm, Rb, G, E = w[0], w[1], w[2], w[3]
    quat_to_dcm_into(q_meas, Rm)
    quat_to_dcm_into(q_body_est, Rb)
    for r in range(3):  # E = R_meas (H_att R̂_body)ᵀ
        for c in range(3):
            G[r, c] = H_att[r, 0] * Rb[0, c] + H_att[r, 1] * Rb[1, c] + H_att[r, 2] * Rb[2, c]
    for r in range(3):
        for c in range(3):
            E[r, c] = Rm[r, 0] * G[c, 0] + Rm[r, 1] * G[c, 1] + Rm[r, 2] * G[c, 2]
    ax0 = 0.5 * (E[2, 1] - E[1, 2])
    ax1 = 0.5 * (E[0, 2] - E[2, 0])
    ax2 = 0.5 * (E[1, 0] - E[0, 1])
    sn = math.sqrt(ax0 * ax0 + ax1 * ax1 + ax2 * ax2)
    ang = math.atan2(sn, 0.5 * (E[0, 0] + E[1, 1] + E[2, 2] - 1.0))
    k = 1.0 if sn < 1e-12 else ang / sn
    r_out[0], r_out[1], r_out[2] = -k * ax0, -k * ax1, -k * ax2


@kernel
def tracker_rows(q_meas, q_body, omega, dt_extrap, R_st_from_body_nom, phi, use_phi, phi_col,
                 lat_col, r_out, H_att, H_phi, H):
    """Residual and measurement rows of one star-tracker sample (the engine's tracker update).

    The attitude q_body (4,) q_body_from_inertial at the last gyro sample is extrapolated by
    dt_extrap [s] with the body rate omega (3,) [rad/s, body] to the measurement's epoch, then
    :func:`tracker_residual` gives r_out (3,) [rad, tracker axes], H_att and H_phi (3, 3).
    H (3, ns) ← 0 with H_att in columns 0..2, H_phi in phi_col..phi_col+2 (if use_phi) and
    ∂h/∂τ = −H_att ω̂ in column lat_col (a latency error δτ is an attitude error −ω̂ δτ).
    Returns |ω̂|² [rad²/s²].
    """
    q_epoch = q_body.copy()
    if dt_extrap != 0.0:
        w = np.empty(11)
        th = w[:3]
        for r in range(3):
            th[r] = omega[r] * dt_extrap
        apply_body_rotation(q_epoch, th, w[3:7], w[7:11])
    tracker_residual(q_meas, q_epoch, R_st_from_body_nom, phi, use_phi, r_out, H_att, H_phi)
    H[:, :] = 0.0
    for r in range(3):
        for c in range(3):
            H[r, c] = H_att[r, c]
            H[r, phi_col + c] = H_phi[r, c]
        H[r, lat_col] = -(H_att[r, 0] * omega[0] + H_att[r, 1] * omega[1] + H_att[r, 2] * omega[2])
    return omega[0] * omega[0] + omega[1] * omega[1] + omega[2] * omega[2]


@kernel
def quat_from_tracker(q_meas, R_st_from_body_nom, phi, use_phi):
    """q_body_from_inertial (4,) implied by a tracker quaternion (inverse of the mounting model)."""
    Rphi = rotvec_to_dcm(phi) if use_phi else np.eye(3)
    return dcm_to_quat((R_st_from_body_nom @ Rphi.T).T @ quat_to_dcm(q_meas))


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
# (:func:`contract_from_internal`, :func:`internal_from_contract`).
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


@kernel
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


@inline_kernel
def select_increments(active, c_all, sg_all, s_all, c_out, sgn_out, s_out):
    """:func:`correct_increment_lin` over the gyros ``active`` (n,) bool, from its results over a
    superset of them (c_all, sg_all, s_all): the same values for the active gyros, zero / zero /
    one for the others (the FDI bank corrects a sample once for all its hypotheses)."""
    for i in range(active.shape[0]):
        if active[i]:
            c_out[i], sgn_out[i], s_out[i] = c_all[i], sg_all[i], s_all[i]
        else:
            c_out[i], sgn_out[i], s_out[i] = 0.0, 0.0, 1.0


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


def contract_from_internal(xp, n):
    """Contract parameters (CONTRACT §1.5, SI) and the Jacobian ∂contract/∂internal.

    xp (5n+3,) internal (b, λ', μ', du', dv', φ2). Per gyro, with a = (1+λ')w − du'v − dv'u:
    1 + λ = |a| = √((1+λ')² + du'² + dv'²), du = du'/(1+λ'), dv = dv'/(1+λ'), μ = μ'(1+λ).
    Returns (xp_contract (5n+3,), J (5n+3, 5n+3)).
    """
    xp = np.ascontiguousarray(xp, dtype=float)
    out, J = xp.copy(), np.eye(xp.size)
    _contract_from_internal(xp, int(n), out, J)
    return out, J


@kernel
def contract_sigma_ud(xp, n, U, d, J, sig):
    """1σ (npar,) of the contract parameters into sig, straight from the UD factors: σ_i² =
    Σ_l d_l (J U_pp)²_il over the parameter block (U (ns, ns) unit upper, d (ns,), parameters
    from state 3), with J = ∂contract/∂internal of :func:`contract_from_internal` (written into
    the work matrix J (npar, npar)); J has at most four entries per row, so the product is taken
    over a row's nonzero entries only (P and J P Jᵀ are never formed)."""
    npar = xp.shape[0]
    for r in range(npar):
        for c in range(npar):
            J[r, c] = 1.0 if r == c else 0.0
    _contract_from_internal(xp, n, np.empty(npar), J)
    cols = np.empty(npar, np.int64)
    vals = np.empty(npar)
    for i in range(npar):
        m = 0
        for k in range(npar):
            if J[i, k] != 0.0:
                cols[m], vals[m] = k, J[i, k]
                m += 1
        if m == 0:
            sig[i] = 0.0
            continue
        acc = 0.0
        lo = cols[0]  # U is upper triangular: row k of U_pp is zero left of column k
        for col in range(lo, npar):
            f = 0.0
            for a in range(m):
                f += vals[a] * U[3 + cols[a], 3 + col]
            acc += d[3 + col] * f * f
        sig[i] = np.sqrt(max(acc, 0.0))


@kernel
def _contract_from_internal(xp, n, out, J):
    """The per-gyro part of :func:`contract_from_internal` into out (copy of xp) and J (= I)."""
    for i in range(n):
        il, im, iu, iv = n + i, 2 * n + i, 3 * n + i, 4 * n + i
        sl, mu, du, dv = 1.0 + xp[il], xp[im], xp[iu], xp[iv]
        na = math.sqrt(sl * sl + du * du + dv * dv)
        out[il] = na - 1.0
        out[im] = mu * na
        out[iu] = du / sl
        out[iv] = dv / sl
        J[il, il], J[il, iu], J[il, iv] = sl / na, du / na, dv / na
        J[im, im] = na
        J[im, il], J[im, iu], J[im, iv] = mu * sl / na, mu * du / na, mu * dv / na
        J[iu, iu], J[iu, il] = 1.0 / sl, -du / (sl * sl)
        J[iv, iv], J[iv, il] = 1.0 / sl, -dv / (sl * sl)


def internal_from_contract(xp_c, n):
    """Inverse of :func:`contract_from_internal` (exact): contract (b, λ, μ, du, dv, φ2) → internal."""
    xp_c = np.asarray(xp_c, dtype=float)
    out = xp_c.copy()
    for i in range(n):
        il, im, iu, iv = n + i, 2 * n + i, 3 * n + i, 4 * n + i
        lam, mu, du, dv = xp_c[il], xp_c[im], xp_c[iu], xp_c[iv]
        sl = (1.0 + lam) / math.sqrt(1.0 + du * du + dv * dv)
        out[il] = sl - 1.0
        out[im] = mu / (1.0 + lam)
        out[iu] = du * sl
        out[iv] = dv * sl
    return out


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
