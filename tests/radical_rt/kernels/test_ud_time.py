"""UD time-update kernels (radical_rt.kernels.ud_time) against dense references: MWGS, the
structured attitude-first update, Agee-Turner rank-one updates and diagonal noise, the reset of
a leading block and state scaling (the random problems of tests/support/ud_problems.py; errors
scale-free, as in test_ud.py)."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from radical_rt._jit import ERR_NONFINITE, ERR_NOT_POSITIVE, ERR_SHAPE, OK
from radical_rt.kernels import ud, ud_time
from tests.support.ud_problems import (
    SETTINGS,
    TOL,
    assert_valid,
    cov,
    nerr,
    problem,
    random_spd,
    seeds,
    sizes,
)


# --------------------------------------------------------------------------- MWGS
@SETTINGS
@given(n=sizes, seed=seeds, r_frac=st.floats(0.0, 1.0))
def test_mwgs_matches_dense(n, seed, r_frac):
    rng, P, U, d = problem(n, seed)
    r = int(round(r_frac * n))
    s = np.sqrt(np.diag(P))
    Phi = s[:, None] * (np.eye(n) + 0.3 * rng.standard_normal((n, n))) / s[None, :]
    G = s[:, None] * rng.standard_normal((n, r))
    q = rng.uniform(0.0, 1.0, r) * (rng.random(r) < 0.8)
    P_ref = Phi @ P @ Phi.T + (G * q) @ G.T
    ws = ud.UDWorkspace(n, m_att=1)  # r_max = n ≥ r: larger work arrays than needed are accepted
    assert ud_time.mwgs_time_update(U, d, Phi, G, q, ws.Y, ws.Dw, ws.c) == OK
    assert_valid(U, d)
    assert nerr(cov(U, d), P_ref) < TOL


def test_mwgs_singular_and_bad_input_change_nothing():
    _, _, U, d = problem(5, 3)
    U0, d0, ws = U.copy(), d.copy(), ud.UDWorkspace(5)
    Phi = np.eye(5)
    Phi[2, :] = 0.0  # zero row, no noise: the result is singular
    G, q = np.zeros((5, 1)), np.zeros(1)
    assert ud_time.mwgs_time_update(U, d, Phi, G, q, ws.Y, ws.Dw, ws.c) == ERR_NOT_POSITIVE
    assert np.array_equal(U, U0) and np.array_equal(d, d0)
    assert ud_time.mwgs_time_update(U, d, np.eye(5), G, -np.ones(1), ws.Y, ws.Dw, ws.c) \
        == ERR_NOT_POSITIVE
    assert ud_time.mwgs_time_update(U, d, np.full((5, 5), np.nan), G, q, ws.Y, ws.Dw, ws.c) \
        == ERR_NONFINITE
    assert ud_time.mwgs_time_update(U, d, np.eye(5), G, q, ws.Y[:, :5], ws.Dw, ws.c) == ERR_SHAPE
    assert np.array_equal(U, U0) and np.array_equal(d, d0)
    G[2, 0], q[0] = 1.0, 0.5  # noise on the zeroed state makes it regular again
    assert ud_time.mwgs_time_update(U, d, Phi, G, q, ws.Y, ws.Dw, ws.c) == OK
    assert_valid(U, d)


# --------------------------------------------------------------------------- structured
@SETTINGS
@given(m=st.integers(1, 3), n=st.integers(1, 40), seed=seeds, q_rank=st.integers(0, 3))
def test_structured_matches_dense(m, n, seed, q_rank):
    n = max(n, m + 1)
    rng, P, U, d = problem(n, seed)
    s = np.sqrt(np.diag(P))
    Phi = np.eye(n)
    Phi[:m, :m] += 0.3 * rng.standard_normal((m, m))
    Phi[:m, m:] = rng.standard_normal((m, n - m))
    Phi = s[:, None] * Phi / s[None, :]
    A = s[:m, None] * rng.standard_normal((m, min(q_rank, m)))
    Q = np.zeros((n, n))
    Q[:m, :m] = A @ A.T  # PSD, possibly singular
    P_ref = Phi @ P @ Phi.T + Q
    U22, d2 = U[m:, m:].copy(), d[m:].copy()
    work = ud_time.structured_work(n, m)
    # non-contiguous views are accepted as they are (numba compiles an 'A'-layout version)
    assert ud_time.structured_time_update(U, d, m, Phi[:m, :m], Phi[:m, m:], Q[:m, :m], work) == OK
    assert_valid(U, d)
    assert np.array_equal(U[m:, m:], U22) and np.array_equal(d[m:], d2)
    assert nerr(cov(U, d), P_ref) < TOL


def test_structured_whole_state_and_errors():
    rng, P, U, d = problem(4, 4)
    Phi = np.eye(4) + 0.2 * rng.standard_normal((4, 4))
    work = ud_time.structured_work(4, 4)
    assert ud_time.structured_time_update(U, d, 4, Phi, np.zeros((4, 0)), np.eye(4), work) == OK
    assert nerr(cov(U, d), Phi @ P @ Phi.T + np.eye(4)) < TOL
    U0, d0 = U.copy(), d.copy()
    Z = np.zeros((3, 3))
    assert ud_time.structured_time_update(U, d, 3, Z, np.zeros((3, 1)), Z, work) == ERR_NOT_POSITIVE
    assert ud_time.structured_time_update(U, d, 3, np.eye(3), np.zeros((3, 2)), Z, work) == ERR_SHAPE
    assert ud_time.structured_time_update(U, d, 3, np.eye(3), np.zeros((3, 1)), Z, work[:, :5]) \
        == ERR_SHAPE
    assert np.array_equal(U, U0) and np.array_equal(d, d0)


# --------------------------------------------------------------------------- Agee-Turner
@SETTINGS
@given(n=sizes, seed=seeds)
def test_agee_turner_matches_dense(n, seed):
    rng, P, U, d = problem(n, seed)
    a = np.sqrt(np.diag(P)) * rng.standard_normal(n) * (rng.random(n) < 0.8)
    a0 = a.copy()
    c = float(10.0 ** rng.uniform(-3, 2))
    assert ud_time.agee_turner(U, d, c, a, np.empty(n)) == OK
    assert np.array_equal(a, a0)
    assert_valid(U, d)
    assert nerr(cov(U, d), P + c * np.outer(a, a)) < TOL


def test_agee_turner_rejects_downdate():
    _, _, U, d = problem(5, 5)
    U0, d0 = U.copy(), d.copy()
    assert ud_time.agee_turner(U, d, -1.0, np.ones(5), np.empty(5)) == ERR_NOT_POSITIVE
    assert ud_time.agee_turner(U, d, np.nan, np.ones(5), np.empty(5)) == ERR_NONFINITE
    assert ud_time.agee_turner(U, d, 0.0, np.ones(5), np.empty(5)) == OK
    assert ud_time.agee_turner(U, d, 1.0, np.ones(4), np.empty(5)) == ERR_SHAPE
    assert np.array_equal(U, U0) and np.array_equal(d, d0)


@SETTINGS
@given(n=sizes, seed=seeds)
def test_add_diagonal_noise_matches_dense(n, seed):
    rng, P, U, d = problem(n, seed)
    k = int(rng.integers(1, n + 1))
    idx = rng.integers(0, n, size=k)  # repeats allowed
    c = np.diag(P)[idx] * rng.uniform(0.0, 2.0, k) * (rng.random(k) < 0.9)
    P_ref = P.copy()
    for i, ci in zip(idx, c, strict=True):
        P_ref[i, i] += ci
    top = int(idx.max())
    U_right, d_right = U[:, top + 1:].copy(), d[top + 1:].copy()
    assert ud_time.add_diagonal_noise(U, d, idx, c, np.empty(n)) == OK
    assert_valid(U, d)
    assert np.array_equal(U[:, top + 1:], U_right) and np.array_equal(d[top + 1:], d_right)
    assert nerr(cov(U, d), P_ref) < TOL


def test_add_diagonal_noise_validates_everything_first():
    _, _, U, d = problem(5, 6)
    U0, d0, a = U.copy(), d.copy(), np.empty(5)
    assert ud_time.add_diagonal_noise(U, d, np.array([0, 5]), np.ones(2), a) == ERR_SHAPE
    assert ud_time.add_diagonal_noise(U, d, np.array([0, 1]), np.array([1.0, -1.0]), a) \
        == ERR_NOT_POSITIVE
    assert ud_time.add_diagonal_noise(U, d, np.array([0, 1]), np.array([1.0, np.inf]), a) \
        == ERR_NONFINITE
    assert np.array_equal(U, U0) and np.array_equal(d, d0)


# --------------------------------------------------------------------------- reset / scale
@SETTINGS
@given(m=st.integers(1, 3), n=st.integers(1, 40), seed=seeds)
def test_reset_leading_block(m, n, seed):
    n = max(n, m + 1)
    rng, P, U, d = problem(n, seed)
    P0 = random_spd(rng, m)
    U22, d2, P22 = U[m:, m:].copy(), d[m:].copy(), cov(U, d)[m:, m:]
    assert ud_time.reset_leading_block(U, d, m, P0, ud_time.structured_work(n, m)) == OK
    assert_valid(U, d)
    assert np.array_equal(U[m:, m:], U22) and np.array_equal(d[m:], d2)
    P_new = cov(U, d)
    assert np.array_equal(P_new[m:, m:], P22)
    assert not np.any(P_new[:m, m:]) and not np.any(U[:m, m:])
    assert nerr(P_new[:m, :m], P0) < 1e-12


def test_reset_rejects_non_spd_without_change():
    _, _, U, d = problem(6, 7)
    U0, d0 = U.copy(), d.copy()
    bad = np.array([[1.0, 2.0], [2.0, 1.0]])
    assert ud_time.reset_leading_block(U, d, 2, bad, ud_time.structured_work(6, 2)) == ERR_NOT_POSITIVE
    assert ud_time.reset_leading_block(U, d, 3, np.eye(2), ud_time.structured_work(6, 3)) == ERR_SHAPE
    assert np.array_equal(U, U0) and np.array_equal(d, d0)


@SETTINGS
@given(n=sizes, seed=seeds)
def test_scale_states(n, seed):
    rng, P, U, d = problem(n, seed)
    s = 10.0 ** rng.uniform(-2, 2, n)
    assert ud_time.scale_states(U, d, s) == OK
    assert_valid(U, d)
    assert nerr(cov(U, d), s[:, None] * P * s[None, :]) < TOL
    U0, d0 = U.copy(), d.copy()
    s[0] = 0.0
    assert ud_time.scale_states(U, d, s) == ERR_NOT_POSITIVE
    assert np.array_equal(U, U0) and np.array_equal(d, d0)
