"""Test oracle: the FDI hypothesis bank as it was written in Python before the bank was compiled
(radical_rt/fdi/monitor.py, HypothesisBank, at commit 12a76bb), numpy solve/slogdet per hypothesis per
tracker sample. Kept verbatim apart from: the imports; the gyro history's former ``take`` as the
module function :func:`take`; public names for the two steps (``propagate_to``,
``update_tracker``, so that a test can trace every tracker sample); and ``final_state``, through
which the monitor's hand-over now reads the winner's state.

It is not the product: tests/radical_rt/fdi/test_fdi_bank.py runs it side by side with the compiled bank
(radical_rt.fdi.fdi_hypotheses.HypothesisBank, kernels in radical_rt.fdi.fdi_bank) and compares the
log-likelihoods and NIS of every tracker sample and the decisions; perf/bench_fdi_bank.py times
both. Known difference by design: an S that is not positive definite gives ll = −inf in the
kernels (Cholesky); here only an exactly singular S raises LinAlgError (an indefinite S would go on
with log|det S|). S = H P Hᵀ + R with R positive definite is positive definite in every case run.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np

from radical_rt.fdi.fdi_detect import chi2_isf
from radical_rt.fdi.fdi_hypotheses import CONSISTENCY_P, NIS_CAP
from radical_rt.kernels import ud
from radical_rt.kernels.model import refresh_axes
from radical_rt.kernels.propagate import propagate_window, sample_work
from radical_rt.kernels.rotation import apply_body_rotation, quat_conj, quat_mul, rotvec_to_quat
from radical_rt.kernels.tracker_model import tracker_residual


def take(buf, t_after: float, t_upto: float):
    """Copies of the buffered gyro samples with t_after < t ≤ t_upto as (t, dt, dθ, status,
    bridged, var_extra), or None: what the gyro history's ``take`` returned before the compiled
    bank (column views of one float and one int block, the memory layout of the clock's batches,
    so that propagate_window runs the engine's compiled specialization)."""
    span = buf.span(t_after, t_upto)
    if span is None:
        return None
    f, i_blk, b_blk, a, z = span
    fb = np.empty_like(f[a:z])
    fb[...] = f[a:z]
    ib = np.empty((z - a, 2), np.int64)
    ib[:, 0] = i_blk[a:z]
    bb = b_blk[a:z].copy()
    return fb[:, 0], fb[:, 1], fb[:, 3:], ib[:, 0], bb, fb[:, 2]


class PythonHypothesisBank:
    """H0 (all gyros) and H_i (gyro i left out): open-loop attitude propagation with the snapshot
    calibration and a Schmidt attitude filter on the tracker samples (considered: every parameter
    state of the snapshot). Log-likelihoods of the tracker innovations decide (docs/fdi.md §3)."""

    def __init__(self, eng, snap, t_alarm: float) -> None:
        n, npar = eng.n_gyro, eng.ns - 3
        self.snap, self.t_alarm = snap, t_alarm
        self.gyros: list[int | None] = [None] + list(range(n))
        self.masks = [np.zeros(n, np.bool_)] + [np.eye(n, dtype=np.bool_)[i] for i in range(n)]
        nh = len(self.gyros)
        self.xp = snap.xp.copy()
        self.A, self.Minv, self.Gp = np.zeros((3, n)), np.eye(3), np.zeros((3, n))
        N = snap.N.copy()
        refresh_axes(self.xp, eng.geo.W, eng.geo.U, eng.geo.V, snap.N.copy(), self.A, self.Minv,
                     self.Gp, N)
        self.N_none = np.zeros((n, 0))
        self._work = sample_work(n)  # propagate_window's work arrays
        P = np.empty((eng.ns, eng.ns))
        ud.ud_to_cov(snap.U, snap.d, P)
        self.Ppp = P[3:, 3:].copy()
        self.Ptt = [P[:3, :3].copy() for _ in range(nh)]
        self.Ptp = [P[:3, 3:].copy() for _ in range(nh)]
        self.q = [snap.q.copy() for _ in range(nh)]
        self.omega = [snap.omega.copy() for _ in range(nh)]
        self.ll = np.zeros(nh)  # log-likelihood (robust, up to a common constant)
        self.nis = np.zeros(nh)  # capped NIS sums
        self.k = 0  # tracker samples processed
        self.t_last = snap.t  # last gyro sample propagated
        self.trk_seq = snap.trk_seq
        self.undetermined = np.zeros(nh, np.int64)
        lay = eng.layout
        self.phi_cols = slice(lay["phi2"].start - 3, lay["phi2"].stop - 3)
        self.lat_col = lay["lat"].start - 3 if "lat" in lay else None
        self.phi = self.xp[self.phi_cols].copy()
        self.tau = float(self.xp[self.lat_col]) if self.lat_col is not None else 0.0
        # propagate_window work arrays
        self.Phi_aa, self.Phi_ap, self.Q_aa = np.eye(3), np.zeros((3, npar)), np.zeros((3, 3))
        self.par_y, self.par_t = np.zeros((2, n)), np.zeros((2, n))
        self.acc_i, self.acc_f, self.th_acc = np.zeros(4, np.int64), np.zeros(3), np.zeros(3)
        self.r, self.H_att, self.H_phi = np.zeros(3), np.zeros((3, 3)), np.zeros((3, 3))
        self.w4, self.dq = np.empty(4), np.empty(4)

    # ------------------------------------------------------------------ propagation
    def propagate_to(self, eng, buf, t_end: float) -> None:
        data = take(buf, self.t_last, t_end)
        if data is None:
            return
        t, dt, dth, status, bridged, var_extra = data
        a, b = 0, len(t)
        arw = eng.si.arw_var_per_s
        for h, mask in enumerate(self.masks):
            self.Phi_aa[:, :] = np.eye(3)
            self.Phi_ap[:, :] = 0.0
            self.Q_aa[:, :] = 0.0
            self.acc_i[:] = 0
            self.acc_f[:] = 0.0
            self.th_acc[:] = 0.0
            k = a
            while k < b:
                k, pflags = propagate_window(
                    dth, dt, status, bridged, var_extra, k, dth.shape[0], mask, self.xp,
                    self.q[h], self.A, eng.geo.W, eng.geo.U, eng.geo.V, self.Minv, self.Gp,
                    self.N_none, self.Phi_aa, self.Phi_ap, self.Q_aa, self.par_y, self.par_t,
                    self.acc_i, self.acc_f, self.th_acc, b - a + 1, arw, self.omega[h],
                    self._work)
                if pflags & 2:
                    self.undetermined[h] += 1
            F, G = self.Phi_aa, self.Phi_ap
            Ptt, Ptp = self.Ptt[h], self.Ptp[h]
            FPtp = F @ Ptp
            GPpp = G @ self.Ppp
            Ptt_new = F @ Ptt @ F.T + FPtp @ G.T + G @ FPtp.T + GPpp @ G.T + self.Q_aa
            self.Ptt[h] = 0.5 * (Ptt_new + Ptt_new.T)
            self.Ptp[h] = FPtp + GPpp
        self.t_last = float(t[b - 1])

    # ------------------------------------------------------------------ tracker update
    def update_tracker(self, eng, j: int, t_epoch: float, q_meas: np.ndarray, n_stars: int) -> None:
        if j == 1:
            R_nom, use_phi = eng.geo.R_st1_from_body, False
        else:
            R_nom, use_phi = eng.geo.R_st2_from_body_nom, True
        sig = np.asarray(eng.si.st_sigma) * math.sqrt(eng.si.st_ref_stars / max(n_stars, 1))
        sig_t = eng.timing_sigma()
        gate = NIS_CAP
        for h in range(len(self.masks)):
            q_ep = self.q[h].copy()
            tau = t_epoch - self.tau - self.t_last
            if tau != 0.0:
                apply_body_rotation(q_ep, self.omega[h] * tau, self.w4, self.dq)
            tracker_residual(q_meas, q_ep, R_nom, self.phi, use_phi, self.r, self.H_att,
                             self.H_phi)
            Ha = self.H_att
            Hp = np.zeros((3, self.Ppp.shape[0]))
            if use_phi:
                Hp[:, self.phi_cols] = self.H_phi
            if self.lat_col is not None:
                Hp[:, self.lat_col] = -(Ha @ self.omega[h])
            v = R_nom @ self.omega[h]
            R = np.diag(sig * sig) + sig_t * sig_t * np.outer(v, v)
            Ptt, Ptp = self.Ptt[h], self.Ptp[h]
            PHt = Ptt @ Ha.T + Ptp @ Hp.T  # cov(δθ, Hx)
            HpPpp = Hp @ self.Ppp
            S = Ha @ PHt + Hp @ (Ptp.T @ Ha.T) + HpPpp @ Hp.T + R
            S = 0.5 * (S + S.T)
            try:
                Sinv_r = np.linalg.solve(S, self.r)
                sign, logdet = np.linalg.slogdet(S)
            except np.linalg.LinAlgError:
                self.ll[h] = -math.inf
                continue
            nis = float(self.r @ Sinv_r)
            self.nis[h] += min(nis, gate)
            self.ll[h] -= 0.5 * (min(nis, gate) + logdet)
            if not nis <= gate:
                continue  # edited like the engine would: no correction
            K = np.linalg.solve(S, PHt.T).T  # (3, 3) gain of the attitude states
            dth = K @ self.r
            q = quat_mul(quat_conj(rotvec_to_quat(dth)), self.q[h])
            self.q[h] = q / (np.linalg.norm(q) * (1.0 if q[3] >= 0 else -1.0))
            Ptt_new = Ptt - K @ PHt.T
            self.Ptt[h] = 0.5 * (Ptt_new + Ptt_new.T)
            self.Ptp[h] = Ptp - K @ (Ha @ Ptp + HpPpp)
        self.k += 1

    # ------------------------------------------------------------------ driver and decision
    def advance(self, eng, gbuf, trk: deque, t_upto: float) -> None:
        """Process the buffered trackers (seq > last) with epoch ≤ t_upto and the gyro samples up
        to the engine's last propagated sample, in the engine's order."""
        # sequence numbers are consecutive in the deque: index the first one not yet processed
        k = max(0, self.trk_seq + 1 - trk[0][0]) if trk else 0
        while k < len(trk):
            seq, epoch, j, q_meas, n_stars = trk[k]
            k += 1
            if epoch > t_upto:
                break
            self.propagate_to(eng, gbuf, epoch)
            self.update_tracker(eng, j, epoch, q_meas, n_stars)
            self.trk_seq = seq
        self.propagate_to(eng, gbuf, eng.t)

    def decision(self, llr_min: float) -> tuple[str, int | None, float]:
        """("isolate", gyro, margin), ("none", None, margin) when H0 wins, or ("wait", …)."""
        if self.k == 0:
            return "wait", None, 0.0
        order = np.argsort(-self.ll, kind="stable")
        best, second = int(order[0]), int(order[1])
        margin = float(self.ll[best] - self.ll[second])
        if margin < llr_min:
            return "wait", None, margin
        if self.nis[best] > chi2_isf(CONSISTENCY_P, 3 * self.k):
            return "wait", None, margin  # even the best hypothesis does not explain the trackers
        gyro = self.gyros[best]
        return ("none" if gyro is None else "isolate"), gyro, margin

    def final_state(self, eng, gbuf, h: int):
        """(q, omega, Ptt, Ptp) of hypothesis h (at eng.t after advance; the monitor's hand-over
        reads them through this)."""
        return self.q[h], self.omega[h], self.Ptt[h], self.Ptp[h]

    def summary(self) -> dict[str, Any]:
        best = float(np.max(self.ll)) if self.k else 0.0
        return {"t_start": self.snap.t, "trackers": self.k,
                "llr": {("all" if g is None else f"ex{g}"): float(self.ll[h] - best)
                        for h, g in enumerate(self.gyros)},
                "nis_mean": {("all" if g is None else f"ex{g}"): float(self.nis[h] / max(self.k, 1))
                             for h, g in enumerate(self.gyros)},
                "undetermined": [int(x) for x in self.undetermined]}

