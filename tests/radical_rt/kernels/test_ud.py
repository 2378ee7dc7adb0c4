"""UD kernels (radical_rt.kernels.ud) against dense references: factor and readout, Bierman,
decorrelation, workspace, ill-conditioning (notes/rimu.md §11.10 (i)-(ii); DESIGN §5). The time
updates are in test_ud_time.py.

Random problems: hypothesis draws the size and a seed (derandomized, so every run is the same and
a failure prints its seed); numpy builds an SPD covariance with eigenvalues spread over 1e4 and
state scales spread over 1e6 (mixed units). Errors are measured scale-free, relative to
sqrt(P_ii P_jj), so a 1e-9 tolerance means the same thing for every state.
"""

from __future__ import annotations

import mpmath
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from radical_rt._jit import ERR_NONFINITE, ERR_NOT_POSITIVE, ERR_SHAPE, OK
from radical_rt.kernels import ud, ud_time
from tests.support.ud_problems import (
    SETTINGS,
    TOL,
    assert_valid,
    cov,
    factors,
    nerr,
    problem,
    random_spd,
    seeds,
    sizes,
)


# --------------------------------------------------------------------------- factor / readout
@SETTINGS
@given(n=sizes, seed=seeds)
def test_factor_roundtrip_and_variances(n, seed):
    _, P, U, d = problem(n, seed)
    assert_valid(U, d)
    assert nerr(cov(U, d), P) < TOL
    var = np.empty(n)
    ud.variances(U, d, var)
    np.testing.assert_allclose(var, np.diag(P), rtol=TOL)
    np.testing.assert_allclose(var, np.diag(cov(U, d)), rtol=1e-14)


def test_factor_diagonal_is_exact_and_bad_input():
    P = np.diag([1e-6, 2.0, 3e8])
    U, d = factors(P)
    assert np.array_equal(U, np.eye(3)) and np.array_equal(d, np.diag(P))
    U, d = np.zeros((3, 3)), np.zeros(3)
    assert ud.factor_ud(np.diag([1.0, -1.0, 1.0]), U, d) == ERR_NOT_POSITIVE
    assert ud.factor_ud(np.array([[1.0, 2.0], [2.0, 1.0]]), U[:2, :2].copy(), d[:2].copy()) \
        == ERR_NOT_POSITIVE
    bad = np.eye(3)
    bad[0, 2] = bad[2, 0] = np.nan
    assert ud.factor_ud(bad, U, d) == ERR_NOT_POSITIVE
    assert ud.factor_ud(np.eye(3), np.zeros((3, 2)), d) == ERR_SHAPE
    P_bad = np.full((3, 3), 7.0)
    ud.ud_to_cov(np.eye(3), np.ones(2), P_bad)
    assert np.all(np.isnan(P_bad))


# --------------------------------------------------------------------------- Bierman
def joseph(P, h, r):
    alpha = h @ P @ h + r
    K = P @ h / alpha
    A = np.eye(len(h)) - np.outer(K, h)
    return A @ P @ A.T + r * np.outer(K, K), K, alpha


def assert_gain(K, K_ref, P, alpha):
    """|ΔK_i| relative to sqrt(P_ii / α) (the largest |K_i| can be)."""
    assert np.max(np.abs(K - K_ref) * np.sqrt(alpha / np.diag(P))) < TOL


@SETTINGS
@given(n=sizes, seed=seeds, sparse=st.booleans())
def test_bierman_matches_joseph(n, seed, sparse):
    rng, P, U, d = problem(n, seed)
    h = rng.standard_normal(n) / np.sqrt(np.diag(P))
    if sparse:  # star-tracker-like row: a few non-zeros only
        h[rng.random(n) < 0.7] = 0.0
        h[rng.integers(n)] = 1.0 / np.sqrt(P[0, 0])
    r = float((h @ P @ h) * 10.0 ** rng.uniform(-3, 1))
    P_ref, K_ref, alpha_ref = joseph(P, h, r)
    assert ud.innovation_variance(U, d, h, r, np.empty(n)) == pytest.approx(alpha_ref, rel=TOL)
    k, f, v = np.empty(n), np.empty(n), np.empty(n)
    status, alpha = ud.bierman_update(U, d, h, r, k, f, v)
    assert status == OK
    assert alpha == pytest.approx(alpha_ref, rel=TOL)
    assert_gain(k, K_ref, P, alpha_ref)
    assert_valid(U, d)
    assert nerr(cov(U, d), P_ref) < TOL


def test_bierman_rejects_bad_input_without_change():
    rng, P, U, d = problem(6, 1)
    U0, d0, ws = U.copy(), d.copy(), ud.UDWorkspace(6)
    h = rng.standard_normal(6)
    for args, code in (((h, 0.0), ERR_NOT_POSITIVE), ((h, -1.0), ERR_NOT_POSITIVE),
                       ((h, np.nan), ERR_NONFINITE), ((np.full(6, np.inf), 1.0), ERR_NONFINITE),
                       ((h[:5].copy(), 1.0), ERR_SHAPE)):
        status, _ = ud.bierman_update(U, d, args[0], args[1], ws.k, ws.f, ws.v)
        assert status == code
        assert np.array_equal(U, U0) and np.array_equal(d, d0)


def test_bierman_zero_row_is_identity():
    _, _, U, d = problem(5, 2)
    U0, d0, ws = U.copy(), d.copy(), ud.UDWorkspace(5)
    status, alpha = ud.bierman_update(U, d, np.zeros(5), 0.25, ws.k, ws.f, ws.v)
    assert status == OK and alpha == 0.25
    assert np.array_equal(U, U0) and np.array_equal(d, d0) and not np.any(ws.k)


# --------------------------------------------------------------------------- decorrelation
@SETTINGS
@given(n=sizes, m=st.integers(1, 6), seed=seeds)
def test_decorrelate_then_scalar_updates_equal_vector_update(n, m, seed):
    rng, P, U, d = problem(n, seed)
    H = rng.standard_normal((m, n)) / np.sqrt(np.diag(P))
    R = random_spd(rng, m, cond_exp=2.0, scale_exp=0.5)
    z = rng.standard_normal(m)
    H_w, z_w, L = np.empty((m, n)), np.empty(m), np.empty((m, m))
    assert ud.decorrelate(H, z, R, H_w, z_w, L) == OK
    L_ref = np.linalg.cholesky(R)
    np.testing.assert_allclose(L_w := np.tril(L), L_ref, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(L_w @ H_w, H, rtol=1e-10, atol=1e-10 * np.abs(H).max())
    np.testing.assert_allclose(L_w @ z_w, z, rtol=1e-10, atol=1e-10 * np.abs(z).max())
    H2, z2 = H.copy(), z.copy()  # outputs may alias the inputs
    assert ud.decorrelate(H2, z2, R, H2, z2, L) == OK
    assert np.array_equal(H2, H_w) and np.array_equal(z2, z_w)
    # m scalar updates with r = 1 equal the dense vector update (Joseph form)
    x = np.zeros(n)
    ws = ud.UDWorkspace(n, m_att=1)
    for i in range(m):
        status, _ = ud.bierman_update(U, d, H_w[i], 1.0, ws.k, ws.f, ws.v)
        assert status == OK
        x += ws.k * (z_w[i] - H_w[i] @ x)
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T
    A = np.eye(n) - K @ H
    P_ref = A @ P @ A.T + K @ R @ K.T
    assert nerr(cov(U, d), P_ref) < 1e-8
    assert np.max(np.abs(x - K @ z) / np.sqrt(np.diag(P))) < 1e-8


def test_decorrelate_errors():
    H, z, out = np.ones((2, 3)), np.ones(2), (np.empty((2, 3)), np.empty(2), np.empty((2, 2)))
    assert ud.decorrelate(H, z, np.array([[1.0, 2.0], [2.0, 1.0]]), *out) == ERR_NOT_POSITIVE
    assert ud.decorrelate(H, z, np.eye(3), *out) == ERR_SHAPE
    assert ud.decorrelate(H, np.array([1.0, np.nan]), np.eye(2), *out) == ERR_NONFINITE


# --------------------------------------------------------------------------- workspace
def test_workspace_shapes_fit_every_kernel():
    n, m = 26, 3
    ws = ud.UDWorkspace(n, m_att=m)
    assert ws.r_max == n and ws.Y.shape == (n, 2 * n) and ws.struct.shape == (m, n + m)
    rng, P, U, d = problem(n, 8)
    G, q = rng.standard_normal((n, 4)), np.ones(4)
    assert ud_time.mwgs_time_update(U, d, np.eye(n), G, q, ws.Y, ws.Dw, ws.c) == OK
    assert ud_time.structured_time_update(U, d, m, np.eye(m), np.zeros((m, n - m)), np.eye(m),
                                     ws.struct) == OK
    assert ud_time.reset_leading_block(U, d, m, np.eye(m), ws.struct) == OK
    assert ud_time.agee_turner(U, d, 1.0, np.ones(n), ws.a) == OK
    H, R = rng.standard_normal((2, n)), np.eye(2)
    assert ud.decorrelate(H, np.ones(2), R, ws.H_w, ws.z_w, ws.L) == OK
    assert ud.bierman_update(U, d, ws.H_w[0], 1.0, ws.k, ws.f, ws.v)[0] == OK
    ud.variances(U, d, ws.var)
    assert np.all(ws.var > 0)
    with pytest.raises(ValueError):
        ud.UDWorkspace(3, m_att=4)


# --------------------------------------------------------------------------- ill-conditioning
def test_long_ill_conditioned_sequence_against_mpmath():
    """3 states with a 1e8 prior, 3000 nearly redundant scalar rows with r = 1e-12.

    The final covariance has condition number ≈ 1e14. The UD factors stay positive definite (by
    construction) and agree with a 50-digit reference; the conventional float64 update
    P ← (I − K h) P loses symmetry and positive definiteness and ends up far from it.
    """
    seed, n, n_up, r = 3, 6, 3000, 1e-12
    rng = np.random.default_rng(seed)
    mpmath.mp.dps = 50
    P0 = np.diag([1e8, 1e8, 1e8, 1.0, 1.0, 1.0])
    base = rng.standard_normal((3, n))
    rows = base[np.arange(n_up) % 3] + 1e-7 * rng.standard_normal((n_up, n))
    U, d = factors(P0)
    ws = ud.UDWorkspace(n, m_att=1)
    P_conv = P0.copy()
    P_mp = mpmath.matrix(P0.tolist())
    r_mp = mpmath.mpf(r)
    worst_gain = worst_gain_scaled = 0.0
    for k in range(n_up):
        h = rows[k]
        status, _ = ud.bierman_update(U, d, h, r, ws.k, ws.f, ws.v)
        assert status == OK, f"step {k}: status {status}"
        Ph = P_conv @ h
        P_conv = P_conv - np.outer(Ph / (h @ Ph + r), h) @ P_conv  # conventional short form
        h_mp = mpmath.matrix(h.tolist())
        Ph_mp = P_mp * h_mp
        alpha_mp = (h_mp.T * Ph_mp)[0] + r_mp
        K_mp = Ph_mp / alpha_mp
        K_ref = np.array([float(v) for v in K_mp])
        dK = np.abs(ws.k - K_ref)
        worst_gain = max(worst_gain, float(np.max(dK) / np.max(np.abs(K_ref))))
        sd = np.array([float(mpmath.sqrt(P_mp[i, i] / alpha_mp)) for i in range(n)])
        worst_gain_scaled = max(worst_gain_scaled, float(np.max(dK / sd)))
        P_mp = P_mp - K_mp * Ph_mp.T
    P_ref = np.array([[float(P_mp[i, j]) for j in range(n)] for i in range(n)])
    eig_ref = np.linalg.eigvalsh(P_ref)
    assert eig_ref[-1] / eig_ref[0] > 1e10  # genuinely ill-conditioned
    assert_valid(U, d)
    P_ud = cov(U, d)
    assert nerr(P_ud, P_ref) < 1e-8, nerr(P_ud, P_ref)
    # K = P h/α is itself ill-conditioned here: float64 K from the exactly rounded P is off by
    # ~1e-3 relative at worst, the UD gain by ~1e-7 (and ~1e-9 on the scale of sqrt(P_ii/α)).
    assert worst_gain < 1e-6 and worst_gain_scaled < 1e-8, (worst_gain, worst_gain_scaled)
    # the conventional update has visibly degraded
    asym = np.max(np.abs(P_conv - P_conv.T)) / np.max(np.abs(P_conv))
    not_pd = np.linalg.eigvalsh(0.5 * (P_conv + P_conv.T))[0] <= 0 or np.any(np.diag(P_conv) <= 0)
    assert asym > 1e-6 and not_pd and nerr(P_conv, P_ref) > 1.0
