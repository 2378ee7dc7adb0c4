"""The star-tracker measurement model of the filter and its Jacobians (Numba kernels).

A tracker measures q_st_from_inertial (4,), scalar-last. Mounting model: R_st_from_inertial =
R_nom R(φ)ᵀ R_body_from_inertial with the nominal mounting R_nom = R_st_from_body_nom (3, 3) and the
misalignment φ (3,) [rad, body axes], estimated per tracker (φ2 of the state,
:mod:`radical_rt.contract.state`). The residual is in tracker axes [rad]; the rows are taken with
respect to the attitude error δθ (body, rad; :mod:`radical_rt.contract.conventions`), δφ and the
latency error δτ [s]. The gyro and parity models are in :mod:`radical_rt.kernels.model`.
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt._jit import kernel
from radical_rt.kernels.rotation import (
    apply_body_rotation,
    dcm_to_quat,
    left_jacobian,
    quat_to_dcm,
    quat_to_dcm_into,
    rotvec_to_dcm,
    rotvec_to_quat_into,
)


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
