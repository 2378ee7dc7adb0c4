"""Random UD problems for the UD kernel tests (tests/radical_rt/kernels): an SPD covariance with
eigenvalues spread over 1e4 and state scales over 1e6 (mixed units), its UD factors, the
covariance back from factors, a scale-free error and the validity of factors."""

from __future__ import annotations

import numpy as np
from hypothesis import settings
from hypothesis import strategies as st

from radical_rt._jit import OK
from radical_rt.kernels import ud

#: scale-free tolerance; hypothesis settings (derandomized: every run the same); sizes and seeds
TOL = 1e-9
SETTINGS = settings(derandomize=True, deadline=None, max_examples=60)
sizes = st.integers(1, 40)
seeds = st.integers(0, 2**32 - 1)


def random_spd(rng, n, cond_exp=4.0, scale_exp=3.0):
    """SPD (n, n): eigenvalues 10^±cond_exp/2, then state scales 10^±scale_exp."""
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    A = (Q * 10.0 ** rng.uniform(-cond_exp / 2, cond_exp / 2, n)) @ Q.T
    s = 10.0 ** rng.uniform(-scale_exp, scale_exp, n)
    A = s[:, None] * A * s[None, :]
    return 0.5 * (A + A.T)


def factors(P):
    """UD factors (U, d) of P (factor_ud must succeed)."""
    n = P.shape[0]
    U, d = np.zeros((n, n)), np.zeros(n)
    assert ud.factor_ud(P, U, d) == OK
    return U, d


def cov(U, d):
    """P = U diag(d) Uᵀ."""
    P = np.empty_like(U)
    ud.ud_to_cov(U, d, P)
    return P


def nerr(P, P_ref):
    """max |P − P_ref|_ij / sqrt(P_ref_ii P_ref_jj) (correlation-scale error)."""
    s = np.sqrt(np.diag(P_ref))
    return float(np.max(np.abs(P - P_ref) / np.outer(s, s)))


def assert_valid(U, d):
    """U unit upper triangular exactly, d positive and finite."""
    assert np.array_equal(np.diag(U), np.ones(len(d)))
    assert np.array_equal(np.tril(U, -1), np.zeros_like(U))
    assert np.all(np.isfinite(U)) and np.all(np.isfinite(d)) and np.all(d > 0)


def problem(n, seed):
    """(rng, P, U, d): a random SPD P of size n from ``seed`` and its factors."""
    rng = np.random.default_rng(seed)
    P = random_spd(rng, n)
    U, d = factors(P)
    return rng, P, U, d
