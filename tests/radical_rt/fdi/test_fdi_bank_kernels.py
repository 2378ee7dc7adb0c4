"""Unit tests of the bank kernels (radical_rt/fdi/fdi_bank.py, fdi_bank_propagate.py) against
dense numpy formulas of docs/fdi.md §3.2, on seeded random inputs; the same tests run again with
NUMBA_DISABLE_JIT=1 in a subprocess (the kernels' source as plain Python)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from radical_rt.fdi.fdi_bank import bank_tracker, decision_due
from radical_rt.fdi.fdi_bank_propagate import bank_flush, bank_propagate, rows_after
from radical_rt.fdi.fdi_detect import chi2_isf
from radical_rt.fdi.fdi_hypotheses import CONSISTENCY_P, HypothesisBank
from radical_rt.kernels.propagate import propagate_window, sample_work
from radical_rt.kernels.rotation import quat_conj, quat_mul, rotvec_to_quat
from radical_rt.kernels.tracker_model import tracker_residual

NH, NPAR, N = 5, 23, 4
PHI_COL, LAT_COL = 20, 22
SEED = 17


def _spd(rng, n, scale):
    a = rng.standard_normal((n, n))
    return scale * (a @ a.T / n + 0.1 * np.eye(n))


def _state(rng):
    """A consistent random bank state: P (3 + npar) SPD per hypothesis, Ppp shared."""
    Ppp = _spd(rng, NPAR, 1e-8)
    Ptt, Ptp = np.empty((NH, 3, 3)), np.empty((NH, 3, NPAR))
    for h in range(NH):
        L = np.linalg.cholesky(Ppp)
        C = 0.3 * rng.standard_normal((3, NPAR)) @ L.T * 1e-1
        Ptt[h] = _spd(rng, 3, 1e-9) + C @ np.linalg.solve(Ppp, C.T)
        Ptp[h] = C
    q = rng.standard_normal((NH, 4))
    q /= np.linalg.norm(q, axis=1)[:, None] * np.sign(q[:, 3:])
    omega = 1e-3 * rng.standard_normal((NH, 3))
    return q, omega, Ptt, Ptp, Ppp


def _rot(rng):
    q = rng.standard_normal(4)
    q /= np.linalg.norm(q)
    from scipy.spatial.transform import Rotation
    return Rotation.from_quat(q).as_matrix()


def _tracker_reference(q_meas, n_stars, R_nom, phi, dt_ex, st_sigma, ref, sig_t, gate, q, omega, Ptt,
                       Ptp, Ppp, ll, nis):
    """Dense numpy form of one tracker sample for every hypothesis (ST2: φ2 and τ columns)."""
    from radical_rt.kernels.rotation import apply_body_rotation
    out = []
    for h in range(NH):
        qe = q[h].copy()
        apply_body_rotation(qe, omega[h] * dt_ex, np.empty(4), np.empty(4))
        r, Ha, Hphi = np.zeros(3), np.zeros((3, 3)), np.zeros((3, 3))
        tracker_residual(q_meas, qe, R_nom, phi, True, r, Ha, Hphi)
        Hp = np.zeros((3, NPAR))
        Hp[:, PHI_COL:PHI_COL + 3] = Hphi
        Hp[:, LAT_COL] = -(Ha @ omega[h])
        H = np.hstack([Ha, Hp])
        P = np.block([[Ptt[h], Ptp[h]], [Ptp[h].T, Ppp]])
        sig = st_sigma * np.sqrt(ref / n_stars)
        v = R_nom @ omega[h]
        R = np.diag(sig**2) + sig_t**2 * np.outer(v, v)
        S = H @ P @ H.T + R
        e = float(r @ np.linalg.solve(S, r))
        logdet = np.linalg.slogdet(S)[1]
        nis[h] += min(e, gate)
        ll[h] -= 0.5 * (min(e, gate) + logdet)
        if e <= gate:
            K = P @ H.T @ np.linalg.inv(S)  # dense gain of every state; the bank keeps rows 0..2
            Pn = P - K @ H @ P
            dq = quat_mul(quat_conj(rotvec_to_quat(K[:3] @ r)), q[h])
            q[h] = dq / (np.linalg.norm(dq) * np.sign(dq[3]))
            Ptt[h], Ptp[h] = 0.5 * (Pn[:3, :3] + Pn[:3, :3].T), Pn[:3, 3:]
        out.append(e)
    return np.array(out)


def _work():
    return np.zeros((12, 3, 3)), np.zeros((3, 3, NPAR)), np.zeros((4, 4))


def test_tracker_kernel_matches_dense_schmidt_update():
    rng = np.random.default_rng(SEED)
    q, omega, Ptt, Ptp, Ppp = _state(rng)
    R_nom = _rot(rng)
    phi = 1e-4 * rng.standard_normal(3)
    # a measurement near hypothesis 0's attitude, so that some NIS pass the gate and some do not:
    # R_st_from_inertial = R(noise) R_nom R(φ2)ᵀ R_body_from_inertial at the extrapolated epoch
    from scipy.spatial.transform import Rotation

    from radical_rt.kernels.rotation import apply_body_rotation
    qe = q[0].copy()
    apply_body_rotation(qe, omega[0] * 0.013, np.empty(4), np.empty(4))
    Rm = (Rotation.from_rotvec(2e-5 * rng.standard_normal(3)).as_matrix() @ R_nom
          @ Rotation.from_rotvec(phi).as_matrix().T @ Rotation.from_quat(qe).as_matrix())
    q_st = Rotation.from_matrix(Rm).as_quat()
    args = (6, R_nom, phi, 0.013, np.array([1.5e-5, 1.5e-5, 1.4e-4]), 9.0, 2e-4, 30.0)
    ref = [x.copy() for x in (q, omega, Ptt, Ptp)] + [np.full(NH, 7.0), np.full(NH, 2.0)]
    e_ref = _tracker_reference(q_st, *args[:2], phi, *args[3:], ref[0], ref[1], ref[2], ref[3], Ppp,
                               ref[4], ref[5])
    ll, nis, nis_k, logdet_k = np.full(NH, 7.0), np.full(NH, 2.0), np.zeros(NH), np.zeros(NH)
    bad = bank_tracker(q_st, 6, R_nom, True, phi, PHI_COL, LAT_COL, 0.013, args[4], 9.0, 2e-4, 30.0,
                       q, omega, Ptt, Ptp, Ppp, ll, nis, nis_k, logdet_k, *_work())
    assert bad == 0
    assert (e_ref <= 30.0).any() and (e_ref > 30.0).any(), e_ref  # both branches exercised
    np.testing.assert_allclose(nis_k, e_ref, rtol=1e-9)
    np.testing.assert_allclose(ll, ref[4], rtol=1e-12)
    np.testing.assert_allclose(nis, ref[5], rtol=1e-12)
    np.testing.assert_allclose(q, ref[0], rtol=0, atol=1e-14)
    np.testing.assert_allclose(Ptt, ref[2], rtol=0, atol=1e-9 * np.abs(ref[2]).max())
    np.testing.assert_allclose(Ptp, ref[3], rtol=0, atol=1e-9 * np.abs(ref[3]).max())


def test_non_positive_definite_S_gives_minus_inf_and_no_correction():
    rng = np.random.default_rng(SEED + 1)
    q, omega, Ptt, Ptp, Ppp = _state(rng)
    Ptt[2] = -1e-3 * np.eye(3)  # S of hypothesis 2 indefinite
    before = [x.copy() for x in (q, Ptt, Ptp)]
    ll, nis, nis_k, logdet_k = np.zeros(NH), np.zeros(NH), np.zeros(NH), np.zeros(NH)
    bad = bank_tracker(q[0].copy(), 9, np.eye(3), False, np.zeros(3), PHI_COL, -1, 0.0,
                       np.full(3, 1e-5), 9.0, 0.0, 30.0, q, omega, Ptt, Ptp, Ppp, ll, nis, nis_k,
                       logdet_k, *_work())
    assert bad == 1 and ll[2] == -np.inf and np.isnan(nis_k[2]) and nis[2] == 0.0
    assert np.array_equal(q[2], before[0][2]) and np.array_equal(Ptt[2], before[1][2])
    assert np.array_equal(Ptp[2], before[2][2])
    others = [0, 1, 3, 4]
    assert np.all(np.isfinite(ll[others])) and np.all(nis_k[others] >= 0.0)


def test_flush_is_the_schmidt_time_update_and_resets():
    rng = np.random.default_rng(SEED + 2)
    _q, _w, Ptt, Ptp, Ppp = _state(rng)
    F = np.stack([_rot(rng) for _ in range(NH)])
    G = 1e-3 * rng.standard_normal((NH, 3, NPAR))
    G[:, :, PHI_COL:] = 0.0  # as propagate_window leaves them
    Q = np.stack([_spd(rng, 3, 1e-12) for _ in range(NH)])
    want_tt = [F[h] @ Ptt[h] @ F[h].T + F[h] @ Ptp[h] @ G[h].T + G[h] @ Ptp[h].T @ F[h].T
               + G[h] @ Ppp @ G[h].T + Q[h] for h in range(NH)]
    want_tp = [F[h] @ Ptp[h] + G[h] @ Ppp for h in range(NH)]
    bank_flush(F, G, Q, Ptt, Ptp, Ppp, np.zeros((3, NPAR)), np.zeros((3, NPAR)), np.zeros((3, 3)))
    for h in range(NH):
        np.testing.assert_allclose(Ptt[h], 0.5 * (want_tt[h] + want_tt[h].T), rtol=1e-12,
                                   atol=1e-12 * np.abs(want_tt[h]).max())
        np.testing.assert_allclose(Ptp[h], want_tp[h], rtol=1e-12, atol=1e-14 * np.abs(Ppp).max())
    assert np.array_equal(F, np.broadcast_to(np.eye(3), F.shape)) and not G.any() and not Q.any()


def test_rows_after_is_searchsorted_right():
    rng = np.random.default_rng(SEED + 3)
    t = np.sort(np.round(rng.uniform(0.0, 10.0, 40), 1))  # with repeated times
    f = np.zeros((50, 7))
    f[5:45, 0] = t
    for lo, hi in ((-1.0, 11.0), (2.0, 2.0), (t[7], t[20]), (3.3, 1.0), (10.5, 12.0)):
        a, z = rows_after(f, 5, 45, lo, hi)
        assert (a, z) == (5 + np.searchsorted(t, lo, "right"), 5 + np.searchsorted(t, hi, "right"))


def test_propagate_runs_compose_like_one_run_of_propagate_window():
    """Two calls over a split sample range give the accumulators and attitude of one
    propagate_window run of the same hypothesis (sample by sample: bit for bit)."""
    rng = np.random.default_rng(SEED + 4)
    m = 30
    W = np.array([[1, 1, 1, 1], [1, -1, 1, -1], [1, 1, -1, -1]], float) / np.sqrt(3.0)
    U_ax, V_ax = np.roll(W, 1, axis=0), np.roll(W, 2, axis=0)
    from radical_rt.kernels.model import refresh_axes
    xp = 1e-5 * rng.standard_normal(5 * N + 3)
    A, Minv, Gp, Nv = np.zeros((3, N)), np.eye(3), np.zeros((3, N)), np.zeros((N, 1))
    refresh_axes(xp, W, U_ax, V_ax, np.array([[0.5], [-0.5], [-0.5], [0.5]]), A, Minv, Gp, Nv)
    f = np.zeros((m + 4, 3 + N))
    f[2:m + 2, 0] = 100.0 + 0.01 * np.arange(1, m + 1)
    f[2:m + 2, 1] = 0.01
    f[2:m + 2, 3:] = 1e-4 * rng.standard_normal((m, N))
    st, br = np.zeros(m + 4, np.int64), np.zeros(m + 4, np.bool_)
    st[10] = 0b0010  # gyro B invalid in one sample: H_B propagates it, the others mask it
    masks = np.zeros((NH, N), np.bool_)
    masks[1:] = np.eye(N, dtype=np.bool_)
    q0 = np.tile(np.array([0.0, 0.0, 0.0, 1.0]), (NH, 1))
    work = (np.zeros((2, N)), np.zeros((2, N)), np.zeros(4, np.int64), np.zeros(3), np.zeros(3))

    def fresh():
        return (q0.copy(), np.zeros((NH, 3)), np.array([f[1, 0]]), np.zeros(NH, np.int64),
                np.repeat(np.eye(3)[None], NH, 0), np.zeros((NH, 3, 5 * N + 3)),
                np.zeros((NH, 3, 3)))

    s = fresh()
    cal = (masks, xp, A, W, U_ax, V_ax, Minv, Gp, np.zeros((N, 0)), 1e-12)
    assert bank_propagate(f, st, br, 2, m + 2, f[13, 0], *cal, *s, *work) == 12
    assert bank_propagate(f, st, br, 2, m + 2, np.inf, *cal, *s, *work) == m - 12
    assert s[2][0] == f[m + 1, 0]
    for h in range(NH):
        q, w = q0[h].copy(), np.zeros(3)
        Pa, Pp, Qa = np.eye(3), np.zeros((3, 5 * N + 3)), np.zeros((3, 3))
        propagate_window(f[2:m + 2, 3:], f[2:m + 2, 1], st[2:m + 2], br[2:m + 2], f[2:m + 2, 2], 0,
                         m, masks[h], xp, q, A, W, U_ax, V_ax, Minv, Gp, np.zeros((N, 0)), Pa, Pp,
                         Qa, *work[:2], np.zeros(4, np.int64), np.zeros(3), np.zeros(3), m + 1,
                         1e-12, w, sample_work(N))
        assert np.array_equal(s[0][h], q) and np.array_equal(s[1][h], w)
        assert np.array_equal(s[4][h], Pa) and np.array_equal(s[5][h], Pp)
        assert np.array_equal(s[6][h], Qa)
    assert not np.array_equal(s[0][0], s[0][1])  # the hypotheses did differ


def test_decision_due_is_the_python_decision_not_waiting():
    """decision_due (the compiled release's test) says True exactly when HypothesisBank._decide
    says anything but "wait", on seeded log-likelihoods with ties, −inf, margins at the
    threshold and NIS sums on both sides of χ²(3K); K beyond the table: True."""
    rng = np.random.default_rng(SEED)
    llr_min = 13.8
    thr = np.array([0.0] + [chi2_isf(CONSISTENCY_P, 3 * k) for k in range(1, 60)])
    bank = HypothesisBank.__new__(HypothesisBank)  # only the decision's state is needed
    bank.gyros = [None, 0, 1, 2, 3]
    seen = {True: 0, False: 0}
    for trial in range(3000):
        k = int(rng.integers(1, 59))
        ll = rng.choice([0.0, -5.0, -13.8, -20.0, -np.inf], size=NH) if trial % 3 == 0 else \
            -np.abs(rng.standard_normal(NH)) * rng.choice([1.0, 10.0, 30.0])
        nis = thr[k] * rng.uniform(0.5, 1.5, NH)
        if trial % 7 == 0:
            nis[:] = thr[k]  # at the threshold: not above it
        bank.ll, bank.nis, bank.k = ll, nis, k
        verdict = bank._decide(llr_min)[0]
        due = decision_due(ll, nis, thr, k, llr_min)
        assert due == (verdict != "wait"), (ll, nis, k, verdict)
        seen[bool(due)] += 1
    assert min(seen.values()) > 100, seen
    assert decision_due(np.array([0.0, -50.0, -60.0, -70.0, -80.0]), np.zeros(NH), thr, 60, llr_min)


@pytest.mark.skipif(os.environ.get("NUMBA_DISABLE_JIT") == "1", reason="already without JIT")
def test_kernels_without_jit():
    """The tests above with NUMBA_DISABLE_JIT=1: the kernels' source as plain Python."""
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1"}
    root = Path(__file__).resolve().parents[3]
    env["PYTHONPATH"] = os.pathsep.join([str(root), env.get("PYTHONPATH", "")])
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", __file__,
                        "-k", "not without_jit"], env=env, cwd=root, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert "7 passed" in r.stdout, r.stdout[-2000:]


def test_numba_cache_fingerprint_covers_the_bank_kernels(tmp_path, monkeypatch):
    """The bank kernels embed propagate/model/ud/updates kernels: their module is one of the
    kernel modules whose contents key every cached kernel of the package (radical_rt._jit)."""
    from radical_rt import _jit
    from radical_rt.fdi import fdi_bank, fdi_bank_propagate
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    monkeypatch.setattr(_jit, "_PACKAGE", pkg)
    for mod in (fdi_bank, fdi_bank_propagate):
        src = Path(mod.__file__)
        (pkg / src.name).write_bytes(src.read_bytes())
        before = _jit._fingerprint(pkg)
        (pkg / src.name).write_bytes(src.read_bytes() + b"\n# edited\n")
        assert _jit._fingerprint(pkg) != before
