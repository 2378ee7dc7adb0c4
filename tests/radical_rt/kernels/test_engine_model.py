"""The engine's internal (linear) gyro parametrization, its Jacobians, the parity sufficient
statistics and the Schmidt consider update (docs/engine.md)."""

import numpy as np
import pytest

from radical_rt.contract.conventions import ARCSEC, DEG_PER_HR, PPM
from radical_rt.contract.geometry import Geometry
from radical_rt.kernels import ud
from radical_rt.kernels.model import (
    correct_increment_lin,
    increment_jacobian_lin,
    parity_from_stats,
    parity_rows_lin,
    refresh_axes,
)
from radical_rt.kernels.parametrization import contract_from_internal, internal_from_contract
from radical_rt.kernels.updates import gated_update_consider

GEO = Geometry()
N_G = GEO.n_gyro
ACT = np.ones(N_G, np.bool_)


def random_contract(rng, scale=1.0):
    """Contract parameters (SI) of the size of the paper's Table 1 limits."""
    n = N_G
    return np.concatenate([rng.uniform(-3, 3, n) * DEG_PER_HR, rng.uniform(-5000, 5000, n) * PPM * scale,
                           rng.uniform(-100, 100, n) * PPM, rng.uniform(-3600, 3600, n) * ARCSEC * scale,
                           rng.uniform(-3600, 3600, n) * ARCSEC * scale,
                           rng.uniform(-1800, 1800, 3) * ARCSEC])


def axes(xp, N_ref=None):
    A, Gp = np.zeros((3, N_G)), np.zeros((3, N_G))
    Minv, N = np.zeros((3, 3)), np.zeros((N_G, N_G - 3))
    assert refresh_axes(xp, GEO.W, GEO.U, GEO.V, GEO.N if N_ref is None else N_ref, A, Minv, Gp, N) == 0
    return A, Minv, Gp, N


def truth_increment(rng, xc, dt=0.01, theta=None):
    """Raw increments from the CONTRACT §1.5 model (noise-free)."""
    n = N_G
    if theta is None:
        theta = rng.normal(size=3) * 0.3 * np.pi / 180 * dt * 3
    b, lam, mu, du, dv = (xc[k * n:(k + 1) * n] for k in range(5))
    a = GEO.W - GEO.V * du - GEO.U * dv
    wt = a / np.linalg.norm(a, axis=0)
    g = wt.T @ theta
    return theta, (1 + lam + mu * np.sign(g)) * g + b * dt


def theta_hat(y, dt, xp):
    A, _, Gp, _ = axes(xp)
    c, sg, s = np.zeros(N_G), np.zeros(N_G), np.zeros(N_G)
    correct_increment_lin(y, dt, xp, ACT, c, sg, s)
    return Gp @ c


def parity(y, dt, xp):
    _, _, _, N = axes(xp)
    c, sg, s = np.zeros(N_G), np.zeros(N_G), np.zeros(N_G)
    correct_increment_lin(y, dt, xp, ACT, c, sg, s)
    return N.T @ c


@pytest.mark.parametrize("seed", range(4))
def test_conversion_round_trip_and_jacobian(seed):
    rng = np.random.default_rng(seed)
    xc = random_contract(rng)
    xi = internal_from_contract(xc, N_G)
    back, J = contract_from_internal(xi, N_G)
    np.testing.assert_allclose(back, xc, rtol=0, atol=1e-15)
    for k in range(xi.size):
        e = np.zeros_like(xi)
        e[k] = 1e-7
        fd = (contract_from_internal(xi + e, N_G)[0] - contract_from_internal(xi - e, N_G)[0]) / 2e-7
        np.testing.assert_allclose(J[:, k], fd, rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("seed", range(4))
def test_internal_model_inverts_truth_exactly(seed):
    """The scaled-axis form with (λ', μ', du', dv') reproduces the contract's model exactly."""
    rng = np.random.default_rng(10 + seed)
    xc = random_contract(rng)
    xi = internal_from_contract(xc, N_G)
    theta, y = truth_increment(rng, xc)
    np.testing.assert_allclose(theta_hat(y, 0.01, xi), theta, rtol=0, atol=1e-15)
    assert np.max(np.abs(parity(y, 0.01, xi))) < 1e-16


def test_internal_model_is_linear_in_scale_and_misalignment():
    """a_i = (1+λ')w_i − du' v_i − dv' u_i: the axes are affine in the parameters (no curvature)."""
    rng = np.random.default_rng(3)
    x1, x2 = (internal_from_contract(random_contract(rng), N_G) for _ in range(2))
    A1, A2, Am = axes(x1)[0], axes(x2)[0], axes(0.5 * (x1 + x2))[0]
    np.testing.assert_allclose(Am, 0.5 * (A1 + A2), rtol=0, atol=1e-15)


@pytest.mark.parametrize("seed", range(4))
def test_increment_and_parity_jacobians_match_finite_differences(seed):
    rng = np.random.default_rng(100 + seed)
    xi = internal_from_contract(random_contract(rng, 0.2), N_G)
    dt = 0.01
    _, y = truth_increment(rng, contract_from_internal(xi, N_G)[0], dt)
    A, Minv, Gp, N = axes(xi)
    c, sg, s = np.zeros(N_G), np.zeros(N_G), np.zeros(N_G)
    correct_increment_lin(y, dt, xi, ACT, c, sg, s)
    th = Gp @ c
    F = np.zeros((3, 5 * N_G))
    increment_jacobian_lin(A.T @ th, sg, s, dt, th, GEO.W, GEO.U, GEO.V, Gp, ACT, F)
    z, H = np.zeros(N_G - 3), np.zeros((N_G - 3, 5 * N_G + 3))
    parity_rows_lin(c, A.T @ th, sg, s, dt, th, N, GEO.W, GEO.U, GEO.V, z, H)
    # Steps: large enough that the rounding of θ̂ (≈ 1e-16 |θ̂|) divided by the step stays well
    # under rtol — a 1e-3 ppm step left ≈ 1.6e-5 of rounding noise against rtol = 1e-5, so the
    # check depended on how the 3×3 inverse happened to round (BLAS/LAPACK build, CPU) —, and
    # small enough that the central difference's O(h²) error is negligible (θ̂ is affine in
    # λ', du', dv' except through (A Aᵀ)⁻¹).
    scale = np.concatenate([[1e-1 * DEG_PER_HR] * N_G, [1e-1 * PPM] * (2 * N_G), [1e-1 * ARCSEC] * (2 * N_G)])
    for k in range(5 * N_G):
        e = np.zeros_like(xi)
        e[k] = scale[k]
        fd = (theta_hat(y, dt, xi + e) - theta_hat(y, dt, xi - e)) / (2 * scale[k])
        np.testing.assert_allclose(F[:, k], fd, rtol=1e-5, atol=1e-9 * np.max(np.abs(fd)) + 1e-18)
        fdz = (parity(y, dt, xi + e) - parity(y, dt, xi - e)) / (2 * scale[k])
        np.testing.assert_allclose(H[:, k], -fdz, rtol=1e-5, atol=1e-9 * np.max(np.abs(fdz)) + 1e-18)


def _stats(ys, dts, xi):
    """Sufficient statistics as propagate.propagate_window accumulates them."""
    py, pt = np.zeros((2, N_G)), np.zeros((2, N_G))
    for y, h in zip(ys, dts, strict=True):
        e = y - xi[:N_G] * h
        row = np.where(e >= 0.0, 0, 1)
        py[row, np.arange(N_G)] += y
        pt[row, np.arange(N_G)] += h
    return py, pt


def _from_stats(py, pt, xi):
    A, _, Gp, N = axes(xi)
    z, H, th, Phi = np.zeros(N_G - 3), np.zeros((N_G - 3, 5 * N_G + 3)), np.zeros(3), np.zeros((3, 5 * N_G))
    parity_from_stats(py, pt, xi, A, Gp, N, GEO.W, GEO.U, GEO.V, z, H, th, Phi)
    return z, H, th, Phi


def test_parity_from_stats_equals_per_sample_sum():
    """Formed from the sums of raw data, the parity z, Θ and rows equal the per-sample sums."""
    rng = np.random.default_rng(5)
    xc = random_contract(rng, 0.2)
    xi_true = internal_from_contract(xc, N_G)
    xi = xi_true + rng.normal(size=xi_true.size) * np.concatenate(
        [[0.1 * DEG_PER_HR] * N_G, [50 * PPM] * N_G, [5 * PPM] * N_G, [30 * ARCSEC] * (2 * N_G), [0] * 3])
    rate = np.array([0.2, -0.1, 0.25]) * np.pi / 180
    ys, dts = [], []
    for k in range(100):
        h = 0.01 * (1 + 4e-5)
        ys.append(truth_increment(rng, xc, h, rate * h * (1 + 0.01 * k / 100))[1] + rng.normal(size=N_G) * 1e-9)
        dts.append(h)
    A, _, Gp, N = axes(xi)
    zs, Hs, ths = np.zeros(N_G - 3), np.zeros((N_G - 3, 5 * N_G + 3)), np.zeros(3)
    c, sg, s = np.zeros(N_G), np.zeros(N_G), np.zeros(N_G)
    for y, h in zip(ys, dts, strict=True):
        correct_increment_lin(y, h, xi, ACT, c, sg, s)
        th = Gp @ c
        ths += th
        parity_rows_lin(c, A.T @ th, sg, s, h, th, N, GEO.W, GEO.U, GEO.V, zs, Hs)
    z, H, th, _ = _from_stats(*_stats(ys, dts, xi), xi)
    # equal up to round-off of sums of ~1e-4 rad increments (the parity is ~1e-7 rad)
    np.testing.assert_allclose(z, zs, rtol=0, atol=1e-16)
    np.testing.assert_allclose(th, ths, rtol=1e-10, atol=1e-16)
    np.testing.assert_allclose(H, Hs, rtol=1e-6, atol=1e-12 * np.abs(Hs).max())


def test_parity_from_stats_jacobians_match_finite_differences():
    rng = np.random.default_rng(6)
    xc = random_contract(rng, 0.2)
    xi = internal_from_contract(xc, N_G)
    rate = np.array([0.3, 0.05, -0.1]) * np.pi / 180
    ys = [truth_increment(rng, xc, 0.01, rate * 0.01)[1] for _ in range(50)]
    py, pt = _stats(ys, [0.01] * 50, xi)
    _, H, _, Phi = _from_stats(py, pt, xi)
    # Steps: large enough that the rounding of θ̂ (≈ 1e-16 |θ̂|) divided by the step stays well
    # under rtol — a 1e-3 ppm step left ≈ 1.6e-5 of rounding noise against rtol = 1e-5, so the
    # check depended on how the 3×3 inverse happened to round (BLAS/LAPACK build, CPU) —, and
    # small enough that the central difference's O(h²) error is negligible (θ̂ is affine in
    # λ', du', dv' except through (A Aᵀ)⁻¹).
    scale = np.concatenate([[1e-1 * DEG_PER_HR] * N_G, [1e-1 * PPM] * (2 * N_G), [1e-1 * ARCSEC] * (2 * N_G)])
    for k in range(5 * N_G):
        e = np.zeros_like(xi)
        e[k] = scale[k]
        zp, _, thp, _ = _from_stats(py, pt, xi + e)
        zm, _, thm, _ = _from_stats(py, pt, xi - e)
        np.testing.assert_allclose(H[:, k], -(zp - zm) / (2 * scale[k]), rtol=1e-4,
                                   atol=1e-9 * np.abs(H).max())
        np.testing.assert_allclose(Phi[:, k], (thp - thm) / (2 * scale[k]), rtol=1e-4,
                                   atol=1e-9 * np.abs(Phi).max())


def test_gated_update_consider_is_the_schmidt_update():
    """Sequential Schmidt: solve-for states get the optimal gain, consider states are not corrected
    and their covariance is kept; the covariance is the Joseph form of the gain actually used."""
    rng = np.random.default_rng(0)
    n, m = 9, 3
    M = rng.normal(size=(n, n))
    P = M @ M.T + np.eye(n)
    U, d = np.eye(n), np.zeros(n)
    ud.factor_ud(P.copy(), U, d)
    H, z, r = rng.normal(size=(m, n)), rng.normal(size=m), np.array([0.5, 1.0, 2.0])
    cons = np.zeros(n, np.bool_)
    cons[3:7] = True
    dx, ws = np.zeros(n), ud.UDWorkspace(n)
    st, nis, ed = gated_update_consider(U, d, dx, H, z, r, 1e9, True, cons, np.zeros((m, n)),
                                        np.zeros((m, m)), np.zeros(m), np.zeros(m), ws.f, ws.v, ws.k, ws.a)
    assert st == 0 and ed == 0
    np.testing.assert_allclose(nis, z @ np.linalg.solve(H @ P @ H.T + np.diag(r), z))
    Pq, x = P.copy(), np.zeros(n)
    for a in range(m):
        h = H[a]
        al = h @ Pq @ h + r[a]
        k = np.where(cons, 0.0, Pq @ h / al)
        x = x + k * (z[a] - h @ x)
        # Joseph form (I − k hᵀ) P (I − k hᵀ)ᵀ + r k kᵀ, expanded
        Pq = Pq - np.outer(k, h @ Pq) - np.outer(Pq @ h, k) + al * np.outer(k, k)
    Pn = np.empty((n, n))
    ud.ud_to_cov(U, d, Pn)
    np.testing.assert_allclose(Pn, Pq, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(dx, x, rtol=1e-12, atol=1e-14)
    np.testing.assert_array_equal(dx[cons], 0.0)
    np.testing.assert_allclose(Pn[np.ix_(cons, cons)], P[np.ix_(cons, cons)], rtol=1e-10)


def test_set_state_rebuilds_derived_geometry():
    """Engine.set_state alone (no checkpoint module) leaves a ready engine: the scaled axes,
    (AAᵀ)⁻¹ and pseudo-inverse derived from xp equal the source's, and N is the saved one."""
    from radical_rt.engine.filter import Engine

    rng = np.random.default_rng(11)
    src = Engine()
    src.xp[:20] = rng.normal(size=20) * 1e-3
    src._refresh()
    src.N[:, 0] *= -1.0  # a basis the fresh engine would not rebuild by itself
    dst = Engine()
    dst.set_state(src.get_state())
    for name in ("A", "Minv", "Gp", "N", "xp", "U", "d"):
        np.testing.assert_array_equal(getattr(dst, name), getattr(src, name), err_msg=name)
    assert not np.array_equal(dst.A, Engine().A)


def test_attitude_error_propagation_matches_nonlinear_model():
    """δθ_k = R(θ̂)ᵀ δθ_{k−1} + F δp (internal parameters), with R_true = R(δθ)ᵀ R̂ (conventions),
    against exact rotations of the truth and of the estimate (scipy)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(7)
    xi_true = internal_from_contract(random_contract(rng, 0.2), N_G)
    dp = np.concatenate([rng.normal(size=5 * N_G) * np.repeat(
        [1e-3 * DEG_PER_HR, 5 * PPM, 5 * PPM, 5 * ARCSEC, 5 * ARCSEC], N_G), np.zeros(3)])
    xi_est = xi_true - dp
    dth0 = rng.normal(size=3) * 5 * ARCSEC
    R_est0 = Rotation.random(random_state=3)
    R_true0 = Rotation.from_rotvec(dth0).inv() * R_est0
    theta, y = truth_increment(rng, contract_from_internal(xi_true, N_G)[0], 0.01)
    A, _, Gp, _ = axes(xi_est)
    c, sg, s = np.zeros(N_G), np.zeros(N_G), np.zeros(N_G)
    correct_increment_lin(y, 0.01, xi_est, ACT, c, sg, s)
    th_hat = Gp @ c
    R_true1 = Rotation.from_rotvec(theta).inv() * R_true0
    R_est1 = Rotation.from_rotvec(th_hat).inv() * R_est0
    dth1 = (R_est1 * R_true1.inv()).as_rotvec()  # R_true = R(δθ)ᵀ R̂ → R̂ R_trueᵀ = R(δθ)
    F = np.zeros((3, 5 * N_G))
    increment_jacobian_lin(A.T @ th_hat, sg, s, 0.01, th_hat, GEO.W, GEO.U, GEO.V, Gp, ACT, F)
    pred = Rotation.from_rotvec(th_hat).as_matrix().T @ dth0 + F @ dp[:5 * N_G]
    np.testing.assert_allclose(dth1, pred, atol=1e-3 * np.linalg.norm(dth1))


def test_contract_sigma_from_ud_equals_the_mapped_covariance():
    """EngineState.contract_sigma (UD factors, no P formed) = sqrt(diag(J P_pp Jᵀ))."""
    from radical_rt.contract.params import ParamTable
    from radical_rt.engine.filter import Engine
    rng = np.random.default_rng(5)
    eng = Engine(ParamTable())
    ns = eng.ns
    eng.U[:, :] = np.triu(rng.normal(scale=0.3, size=(ns, ns)), 1) + np.eye(ns)
    eng.d[:] = rng.uniform(0.5, 2.0, ns) * 1e-8
    eng.xp[:23] = internal_from_contract(random_contract(rng), N_G)
    eng.xp[23:] = 1e-3  # the tracker latency state
    P = eng.U @ np.diag(eng.d) @ eng.U.T
    _, J = contract_from_internal(eng.xp, N_G)
    want = np.sqrt(np.diag(J @ P[3:, 3:] @ J.T))
    np.testing.assert_allclose(eng.contract_sigma(), want, rtol=1e-12)
    np.testing.assert_allclose(np.sqrt(np.diag(eng.contract_params()[1])), want, rtol=1e-12)
