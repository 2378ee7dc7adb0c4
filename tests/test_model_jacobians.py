"""Filter model Jacobians against finite differences, and the attitude-error convention against scipy."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from radical_rt.conventions import ARCSEC, DEG_PER_HR, PPM
from radical_rt.geometry import Geometry
from radical_rt.model import (
    correct_increment,
    increment_jacobian,
    masked_pinv,
    parity_rows,
    refresh_geometry,
    tracker_residual,
)

GEO = Geometry()
N_G = GEO.n_gyro


def random_params(rng):
    n = N_G
    return np.concatenate([rng.uniform(-3, 3, n) * DEG_PER_HR, rng.uniform(-800, 800, n) * PPM,
                           rng.uniform(-60, 60, n) * PPM, rng.uniform(-900, 900, n) * ARCSEC,
                           rng.uniform(-900, 900, n) * ARCSEC, rng.uniform(-1800, 1800, 3) * ARCSEC])


def geometry_arrays(xp, N_ref=None):
    n = N_G
    Wt, dWdu, dWdv, Gp = (np.zeros((3, n)) for _ in range(4))
    Minv, N = np.zeros((3, 3)), np.zeros((n, n - 3))
    N_ref = GEO.N if N_ref is None else N_ref
    assert refresh_geometry(xp, GEO.W, GEO.U, GEO.V, N_ref, Wt, dWdu, dWdv, Minv, Gp, N) == 0
    return Wt, dWdu, dWdv, Minv, Gp, N


def theta_hat(y, dt, xp):
    """The filter's body increment for raw increments y with parameters xp."""
    Wt, _, _, _, Gp, _ = geometry_arrays(xp)
    c, sg, s = np.zeros(N_G), np.zeros(N_G), np.zeros(N_G)
    correct_increment(y, dt, xp, np.ones(N_G, np.bool_), c, sg, s)
    return Gp @ c


def parity(y, dt, xp):
    _, _, _, _, _, N = geometry_arrays(xp)
    c, sg, s = np.zeros(N_G), np.zeros(N_G), np.zeros(N_G)
    correct_increment(y, dt, xp, np.ones(N_G, np.bool_), c, sg, s)
    return N.T @ c


def make_increment(rng, xp_true, dt=0.01):
    """Raw increments from the contract's truth model (noise-free) for a random body increment."""
    theta = rng.normal(size=3) * 0.3 * np.pi / 180 * dt * 3
    n = N_G
    b, lam, mu, du, dv = (xp_true[k * n:(k + 1) * n] for k in range(5))
    a = GEO.W - GEO.V * du - GEO.U * dv
    wt = a / np.linalg.norm(a, axis=0)
    g = wt.T @ theta
    return theta, (1 + lam + mu * np.sign(g)) * g + b * dt


@pytest.mark.parametrize("seed", range(5))
def test_filter_inverts_truth_model_exactly(seed):
    rng = np.random.default_rng(seed)
    xp = random_params(rng)
    theta, y = make_increment(rng, xp)
    np.testing.assert_allclose(theta_hat(y, 0.01, xp), theta, rtol=0, atol=1e-15)
    assert np.max(np.abs(parity(y, 0.01, xp))) < 1e-16


@pytest.mark.parametrize("seed", range(5))
def test_increment_and_parity_jacobians_match_finite_differences(seed):
    rng = np.random.default_rng(100 + seed)
    xp = random_params(rng)
    dt = 0.01
    _, y = make_increment(rng, xp, dt)
    Wt, dWdu, dWdv, Minv, Gp, N = geometry_arrays(xp)
    c, sg, s = np.zeros(N_G), np.zeros(N_G), np.zeros(N_G)
    act = np.ones(N_G, np.bool_)
    correct_increment(y, dt, xp, act, c, sg, s)
    th = Gp @ c
    F = np.zeros((3, 5 * N_G))
    increment_jacobian(Wt.T @ th, sg, s, dt, th, Wt, dWdu, dWdv, Minv, Gp, act, F)
    z, H = np.zeros(N_G - 3), np.zeros((N_G - 3, 5 * N_G + 3))
    parity_rows(c, Wt.T @ th, sg, s, dt, th, N, dWdu, dWdv, z, H)
    scale = np.concatenate([[1e-3 * DEG_PER_HR] * N_G, [1e-3 * PPM] * (2 * N_G), [1e-3 * ARCSEC] * (2 * N_G)])
    for k in range(5 * N_G):
        e = np.zeros_like(xp)
        e[k] = scale[k]
        fd = (theta_hat(y, dt, xp + e) - theta_hat(y, dt, xp - e)) / (2 * scale[k])
        np.testing.assert_allclose(F[:, k], fd, rtol=1e-5, atol=1e-9 * np.max(np.abs(fd)) + 1e-18)
        fdz = (parity(y, dt, xp + e) - parity(y, dt, xp - e)) / (2 * scale[k])
        # H = −∂z/∂p̂ (δ = true − estimate)
        np.testing.assert_allclose(H[:, k], -fdz, rtol=1e-5, atol=1e-9 * np.max(np.abs(fdz)) + 1e-18)


def test_masked_pinv_uses_only_active_gyros():
    Wt = GEO.W.copy()
    act = np.array([True, True, False, True])
    Minv, Gp = np.zeros((3, 3)), np.zeros((3, 4))
    assert masked_pinv(Wt, act, Minv, Gp) == 3
    np.testing.assert_allclose(Gp[:, 2], 0)
    np.testing.assert_allclose(Gp[:, act] @ Wt[:, act].T, np.eye(3), atol=1e-14)
    assert masked_pinv(Wt, np.array([True, False, False, True]), Minv, Gp) == -1


def test_attitude_error_propagation_matches_nonlinear_model():
    """δθ_k = R(θ̂)ᵀ δθ_{k−1} + F δp, with R_true = R(δθ)ᵀ R̂ (conventions.py)."""
    rng = np.random.default_rng(7)
    xp_true = random_params(rng)
    dp = np.concatenate([rng.normal(size=5 * N_G) * np.repeat([1e-3 * DEG_PER_HR, 5 * PPM, 5 * PPM,
                                                                 5 * ARCSEC, 5 * ARCSEC], N_G), np.zeros(3)])
    xp_est = xp_true - dp
    dth0 = rng.normal(size=3) * 5 * ARCSEC
    R_est0 = Rotation.random(random_state=3)
    R_true0 = Rotation.from_rotvec(dth0).inv() * R_est0
    theta, y = make_increment(rng, xp_true, 0.01)
    th_hat = theta_hat(y, 0.01, xp_est)
    R_true1 = Rotation.from_rotvec(theta).inv() * R_true0
    R_est1 = Rotation.from_rotvec(th_hat).inv() * R_est0
    dth1 = (R_est1 * R_true1.inv()).as_rotvec()  # R_true = R(δθ)ᵀ R̂ → R̂ R_trueᵀ = R(δθ)
    Wt, dWdu, dWdv, Minv, Gp, N = geometry_arrays(xp_est)
    c, sg, s = np.zeros(N_G), np.zeros(N_G), np.zeros(N_G)
    correct_increment(y, 0.01, xp_est, np.ones(N_G, np.bool_), c, sg, s)
    F = np.zeros((3, 5 * N_G))
    increment_jacobian(Wt.T @ (Gp @ c), sg, s, 0.01, Gp @ c, Wt, dWdu, dWdv, Minv, Gp, np.ones(N_G, np.bool_), F)
    pred = Rotation.from_rotvec(th_hat).as_matrix().T @ dth0 + F @ dp[:5 * N_G]
    np.testing.assert_allclose(dth1, pred, atol=1e-3 * np.linalg.norm(dth1))


@pytest.mark.parametrize("j", [1, 2])
def test_tracker_residual_and_jacobians(j):
    """r = −rotvec(R_meas R̂ᵀ) ≈ H_att δθ + H_phi δφ for the contract's mountings (scipy oracle)."""
    rng = np.random.default_rng(11 + j)
    R_nom = GEO.R_st1_from_body if j == 1 else GEO.R_st2_from_body_nom
    phi_hat = rng.normal(size=3) * 1500 * ARCSEC if j == 2 else np.zeros(3)
    dth = rng.normal(size=3) * 20 * ARCSEC
    dphi = rng.normal(size=3) * 20 * ARCSEC if j == 2 else np.zeros(3)
    R_b_est = Rotation.random(random_state=j)
    R_b_true = Rotation.from_rotvec(dth).inv() * R_b_est
    # CONTRACT §1.4: R_st2_from_body = R_nom @ R(phi2)ᵀ
    R_meas = Rotation.from_matrix(R_nom @ Rotation.from_rotvec(phi_hat + dphi).as_matrix().T) * R_b_true
    r, Ha, Hp = np.zeros(3), np.zeros((3, 3)), np.zeros((3, 3))
    tracker_residual(R_meas.as_quat(), R_b_est.as_quat(), R_nom, phi_hat, j == 2, r, Ha, Hp)
    pred = Ha @ dth + Hp @ dphi
    np.testing.assert_allclose(r, pred, atol=2e-3 * np.linalg.norm(r))
    if j == 1:
        np.testing.assert_array_equal(Hp, 0)
        np.testing.assert_array_equal(Ha, R_nom)
