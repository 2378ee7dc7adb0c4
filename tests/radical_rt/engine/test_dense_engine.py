"""The dense-covariance reference (tests/oracles/dense_engine.py) runs the same filter as the UD engine.

Kernel level (one operation on a random SPD covariance, against the UD kernels): time update,
ordinary and Schmidt-consider gated updates agree to 1e-12 relative (rounding only).

End to end (two short disjoint streams with a warm start + bump between them, slews from 20 s so
that the tracker timing term, the consider updates, the parity and the regressor reliability are
all exercised): the same decisions (used / edited / consider counters) and the same final state to
a stated tolerance — parameters within 1e-6 σ, attitude within 1e-9 rad, σ within 1e-8 relative,
covariance within 1e-8 of the UD σ_i σ_j. Measured on this run: 2.3e-10 σ, 1.7e-14 rad, 1.2e-10
(σ) and 2.4e-10 (covariance): rounding differences, propagated through the relinearizations.
"""

import numpy as np
import pytest

from radical_rt.engine.filter import Engine
from radical_rt.kernels import ud, ud_time
from radical_rt.kernels.updates import gated_update, gated_update_consider
from replayer.synth import synthesize
from tests.oracles.dense_engine import DenseEngine, compare, make_processor
from tests.oracles.dense_kernels import dense_gated_update, dense_time_update

N = 27


def _random_ud(rng, n=N):
    A = rng.standard_normal((n, n))
    P = A @ A.T + n * np.diag(10.0 ** rng.uniform(-3, 1, n))
    U, d = np.eye(n), np.ones(n)
    assert ud.factor_ud(P, U, d) == 0
    Pud = np.empty((n, n))
    ud.ud_to_cov(U, d, Pud)
    return U, d, Pud


def test_dense_time_update_matches_structured_ud():
    rng = np.random.default_rng(11)
    U, d, P = _random_ud(rng)
    Phi_aa = np.eye(3) + 0.01 * rng.standard_normal((3, 3))
    Phi_ap = rng.standard_normal((3, N - 3))
    B = rng.standard_normal((3, 3))
    Q = B @ B.T
    assert ud_time.structured_time_update(U, d, 3, Phi_aa, Phi_ap, Q, ud_time.structured_work(N)) == 0
    assert dense_time_update(P, 3, Phi_aa, Phi_ap, Q, np.zeros((3, N))) == 0
    Pud = np.empty((N, N))
    ud.ud_to_cov(U, d, Pud)
    Phi = np.eye(N)
    Phi[:3, :3], Phi[:3, 3:] = Phi_aa, Phi_ap
    scale = np.sqrt(np.outer(np.diag(Pud), np.diag(Pud)))
    assert np.max(np.abs(P - Pud) / scale) < 1e-12
    assert np.array_equal(P, P.T)


@pytest.mark.parametrize("with_consider", [False, True])
def test_dense_joseph_update_matches_bierman(with_consider):
    rng = np.random.default_rng(12 + with_consider)
    U, d, P = _random_ud(rng)
    m = 3
    H = rng.standard_normal((m, N))
    z = rng.standard_normal(m)
    r = 10.0 ** rng.uniform(-1, 1, m)
    consider = np.zeros(N, dtype=np.bool_)
    if with_consider:
        consider[5:17] = True
    dx_ud, dx_dn = np.zeros(N), np.zeros(N)
    F, S1, inn1, sig1 = np.zeros((m, N)), np.zeros((m, m)), np.zeros(m), np.zeros(m)
    f, v, k, a = (np.zeros(N) for _ in range(4))
    if with_consider:
        st, nis_ud, ed = gated_update_consider(U, d, dx_ud, H, z, r, 1e9, True, consider, F, S1,
                                               inn1, sig1, f, v, k, a)
    else:
        st, nis_ud, ed = gated_update(U, d, dx_ud, H, z, r, 1e9, True, F, S1, inn1, sig1, f, v, k)
    assert st == 0 and ed == 0
    S2, inn2, sig2 = np.zeros((m, m)), np.zeros(m), np.zeros(m)
    st, nis_dn, ed = dense_gated_update(P, dx_dn, H, z, r, 1e9, True, consider, S2, inn2, sig2,
                                        np.zeros((N, m)), np.zeros(N), np.zeros(N))
    assert st == 0 and ed == 0
    assert nis_dn == pytest.approx(nis_ud, rel=1e-12)
    Pud = np.empty((N, N))
    ud.ud_to_cov(U, d, Pud)
    scale = np.sqrt(np.outer(np.diag(Pud), np.diag(Pud)))
    assert np.max(np.abs(P - Pud) / scale) < 1e-12
    assert np.max(np.abs(dx_dn - dx_ud) / np.sqrt(np.diag(Pud))) < 1e-12
    if with_consider:  # consider states: not corrected, covariance block kept
        assert np.all(dx_dn[consider] == 0.0)


def _scenario(start: float) -> str:
    moves = [("x", 10.0), ("x", -20.0), ("z", 10.0)]
    lines = ['base = "2006216"', f"t_start_s = {start!r}", "[maneuver]", "start_s = 20.0"]
    for axis, angle in moves:
        lines += ["[[maneuver.moves]]", f'axis = "{axis}"', f"angle_deg = {angle}", "hold_s = 5.0"]
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    d = tmp_path_factory.mktemp("dense")
    paths = []
    for i, (start, dur) in enumerate(((1000.0, 150.0), (2000.0, 100.0))):
        toml = d / f"s{i}.toml"
        toml.write_text(_scenario(start))
        paths.append(d / f"s{i}.mcap")
        synthesize(str(toml), str(paths[-1]), seed=7 + i, duration=dur)
    out = {}
    for cls in (Engine, DenseEngine):
        sp = make_processor(cls)
        for i, p in enumerate(paths):
            if i:
                sp.end_stream("warm")  # warm start + the table's bump, as `radical process`
            _feed(sp, p)
        sp.end_stream(None)
        out[cls.__name__] = sp.engine
    return out["Engine"], out["DenseEngine"]


def _feed(sp, path):
    from radical_rt.apps.batch import INPUTS
    from radical_rt.io.archive import ArchiveReader

    with ArchiveReader(str(path)) as reader:
        for topic, _, data in reader.iter_raw(topics=list(INPUTS)):
            sp.feed(topic[1:], data)


def test_same_decisions(both):
    e_ud, e_dn = both
    for key in ("st1_used", "st2_used", "parity_used", "st1_edited", "st2_edited", "parity_edited",
                "st1_consider", "st2_consider", "warm_starts", "bumps", "att_inits",
                "numeric_faults"):
        assert e_ud.counters.get(key, 0) == e_dn.counters.get(key, 0), key
    # every covariance path ran: consider tracker updates, parity updates, warm start with bump
    assert e_ud.counters["st1_consider"] > 100 and e_ud.counters["parity_used"] > 100
    assert e_ud.counters["warm_starts"] == 1 and e_ud.counters["bumps"] == 1
    assert e_ud.counters.get("numeric_faults", 0) == 0


def test_same_estimates_and_covariance(both):
    e_ud, e_dn = both
    c = compare(e_ud, e_dn)
    assert c["max_param_diff_sigma"] < 1e-6, c
    assert c["att_diff_rad"] < 1e-9, c
    assert c["max_sigma_rel_diff"] < 1e-8, c
    assert c["max_cov_diff_corr"] < 1e-8, c
    assert np.array_equal(e_dn.P, e_dn.P.T)
    # the U, d the dense engine hands to other readers (checkpoints, FDI) factor its P
    P = np.empty_like(e_dn.P)
    ud.ud_to_cov(e_dn.U, e_dn.d, P)
    assert np.max(np.abs(P - e_dn.P) / np.sqrt(np.outer(np.diag(P), np.diag(P)))) < 1e-12
    s_ud, s_dn = e_ud.sigmas(), e_dn.sigmas()  # contract σ (outputs) through both paths
    for g in s_ud:
        assert s_dn[g] == pytest.approx(s_ud[g], rel=1e-8), g
