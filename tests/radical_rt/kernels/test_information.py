"""The excitation monitor's numbers (radical_rt.kernels.information) against numpy and LAPACK
(slogdet, G P Gᵀ) on seeded covariances of the engine's size and conditioning, and the cases
without a factorisation (indefinite block, zero or NaN variance)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from radical_rt.contract.state import StateLayout
from radical_rt.engine.excitation import _axis_rows
from radical_rt.kernels.information import excitation_numbers, excitation_work, unit_logdet


def _covariance(rng, ns: int) -> np.ndarray:
    """A positive definite (ns, ns) matrix with variances from 1e-24 to 1e-2 (rad², the engine's
    range) and correlations up to ≈ 0.99."""
    A = rng.standard_normal((ns, ns))
    C = A @ A.T + 0.02 * ns * np.eye(ns)
    d = 1.0 / np.sqrt(np.diag(C))
    scale = 10.0 ** rng.uniform(-12, -1, ns)
    return (C * d[:, None] * d[None, :]) * scale[:, None] * scale[None, :]


@pytest.fixture(scope="module")
def setup():
    layout = StateLayout(4)
    rng = np.random.default_rng(11)
    W, U, V = (rng.standard_normal((3, 4)) for _ in range(3))
    idx = np.concatenate([np.arange(layout[g].start, layout[g].stop) for g in ("lam", "du", "dv")])
    return layout, idx, _axis_rows(layout, W, U, V)


@pytest.mark.parametrize("seed", range(6))
def test_numbers_match_numpy(setup, seed):
    layout, idx, G = setup
    ns = layout.n_states
    P = _covariance(np.random.default_rng(seed), ns)
    lv, row_var = np.empty(ns + 1), np.empty(G.shape[0])
    excitation_numbers(P, idx, G, lv, row_var, excitation_work(len(idx)))
    var = np.diag(P)
    np.testing.assert_allclose(lv[:ns], np.log(var), rtol=1e-14, atol=0)
    blk = P[np.ix_(idx, idx)]
    sign, ld = np.linalg.slogdet(blk / np.sqrt(np.outer(np.diag(blk), np.diag(blk))))
    assert sign > 0
    assert lv[ns] == pytest.approx(ld + np.log(var[idx]).sum(), rel=1e-12, abs=1e-9)
    np.testing.assert_allclose(row_var, np.sum((G @ P) * G, axis=1), rtol=1e-10)


def test_no_factorisation_gives_the_sum_alone(setup):
    layout, idx, G = setup
    ns = layout.n_states
    P = _covariance(np.random.default_rng(3), ns)
    i, j = idx[0], idx[1]
    P[i, j] = P[j, i] = 1.5 * math.sqrt(P[i, i] * P[j, j])  # a correlation above 1: indefinite
    lv = np.empty(ns + 1)
    excitation_numbers(P, idx, G, lv, np.empty(G.shape[0]), excitation_work(len(idx)))
    assert lv[ns] == pytest.approx(lv[idx].sum(), rel=1e-15)
    ok, value = unit_logdet(P, idx, excitation_work(len(idx)))
    assert not ok and value == 0.0
    Q = P.copy()
    Q[i, i] = 0.0
    assert not unit_logdet(Q, idx, excitation_work(len(idx)))[0]
    Q[i, i] = np.nan
    assert not unit_logdet(Q, idx, excitation_work(len(idx)))[0]
    lv_q = np.empty(ns + 1)
    excitation_numbers(Q, idx, G, lv_q, np.empty(G.shape[0]), excitation_work(len(idx)))
    assert math.isnan(lv_q[i]) and math.isnan(lv_q[ns])  # a NaN variance shows


def test_floor_and_no_rows(setup):
    layout, idx, _G = setup
    ns = layout.n_states
    P = _covariance(np.random.default_rng(5), ns)
    P[0, 0] = -1e-30  # rounding below zero
    lv = np.empty(ns + 1)
    excitation_numbers(P, idx, np.zeros((0, ns)), lv, np.empty(0), excitation_work(len(idx)))
    assert lv[0] == math.log(1e-300)
