"""The gated vector update against a dense Joseph-form Kalman update."""

import numpy as np
import pytest

from radical_rt.kernels import ud
from radical_rt.kernels.updates import UPDATE_ACCEPTED, UPDATE_EDITED, gated_update


def _run(P, H, z, rd, dx0, gate):
    n, m = P.shape[0], H.shape[0]
    U, d = np.eye(n), np.ones(n)
    assert ud.factor_ud(P, U, d) == 0
    dx = dx0.copy()
    F, S, inn, sig = np.zeros((m, n)), np.zeros((m, m)), np.zeros(m), np.zeros(m)
    f, v, k = np.zeros(n), np.zeros(n), np.zeros(n)
    st, nis, acc = gated_update(U, d, dx, H, z, rd, gate, True, F, S, inn, sig, f, v, k)
    Pout = np.zeros((n, n))
    ud.ud_to_cov(U, d, Pout)
    return st, nis, acc, Pout, dx, inn, sig


@pytest.mark.parametrize("seed", range(6))
def test_matches_dense_joseph(seed):
    rng = np.random.default_rng(seed)
    n, m = 26, 3
    A = rng.normal(size=(n, n))
    P = A @ A.T + n * np.eye(n)
    H = rng.normal(size=(m, n))
    rd = rng.uniform(0.5, 2, m)
    dx0 = rng.normal(size=n) * 0.1
    z = H @ dx0 + rng.normal(size=m)
    st, nis, acc, Pu, dx, inn, sig = _run(P, H, z, rd, dx0, 1e9)
    R = np.diag(rd)
    S = H @ P @ H.T + R
    K = P @ H.T @ np.linalg.inv(S)
    IKH = np.eye(n) - K @ H
    Pj = IKH @ P @ IKH.T + K @ R @ K.T
    assert st == 0 and acc == UPDATE_ACCEPTED
    np.testing.assert_allclose(Pu, Pj, rtol=1e-9, atol=1e-9 * np.max(np.abs(Pj)))
    np.testing.assert_allclose(dx, dx0 + K @ (z - H @ dx0), rtol=1e-9, atol=1e-12)
    innov = z - H @ dx0
    assert nis == pytest.approx(innov @ np.linalg.solve(S, innov), rel=1e-10)
    np.testing.assert_allclose(sig, np.sqrt(np.diag(S)), rtol=1e-12)


def test_edit_leaves_state_untouched():
    rng = np.random.default_rng(9)
    n = 10
    P = np.eye(n)
    H = rng.normal(size=(3, n))
    z = np.array([100.0, -100.0, 50.0])
    st, nis, acc, Pu, dx, _, _ = _run(P, H, z, np.ones(3), np.zeros(n), 30.0)
    assert acc == UPDATE_EDITED and nis > 30.0
    np.testing.assert_allclose(Pu, P, atol=1e-15)
    np.testing.assert_array_equal(dx, 0.0)


def test_spd_quadratic_matches_solve_and_flags_indefinite():
    from radical_rt.kernels.updates import spd_quadratic
    rng = np.random.default_rng(11)
    for m in (1, 2, 3, 5):
        A = rng.normal(size=(m, m))
        S = A @ A.T + 0.1 * np.eye(m)
        v = rng.normal(size=m)
        np.testing.assert_allclose(spd_quadratic(S, v), v @ np.linalg.solve(S, v), rtol=1e-12)
    assert np.isnan(spd_quadratic(np.diag([1.0, -1.0, 2.0]), np.ones(3)))
    assert np.isnan(spd_quadratic(np.array([[1.0, 2.0], [2.0, 1.0]]), np.ones(2)))
