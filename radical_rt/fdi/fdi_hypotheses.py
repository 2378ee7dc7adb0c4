"""The FDI hypothesis bank (docs/fdi.md §3): H0 (all gyros) and H_i (gyro i left out), compiled.

Each hypothesis is an open-loop attitude propagation with the snapshot calibration and a Schmidt
attitude filter on the buffered tracker samples whose considered states are every parameter of the
snapshot (gyro calibration, ST2 misalignment φ2, tracker latency). The log-likelihoods of the
tracker innovations decide. The arithmetic is in :mod:`radical_rt.fdi.fdi_bank`: one kernel call per
tracker sample for all hypotheses (the gyro samples up to its epoch, the covariance, the update);
this class keeps the stacked state, routes the monitor's buffers to the kernels and takes the
decision.
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

from radical_rt.fdi.fdi_bank import (
    BF_ARW,
    BF_GATE,
    BF_LLR_MIN,
    BF_REF_STARS,
    BF_TAU,
    BI_BAD,
    BI_END,
    BI_I0,
    BI_K,
    BI_LAT_COL,
    BI_ON,
    BI_PHI_COL,
    BI_STEPS,
    bank_run,
    decide,
)
from radical_rt.fdi.fdi_bank_pack import idle_buffers, pack_bank
from radical_rt.fdi.fdi_bank_propagate import bank_flush, bank_propagate
from radical_rt.fdi.fdi_detect import chi2_isf
from radical_rt.kernels import ud
from radical_rt.kernels.model import refresh_axes

NIS_CAP = 30.0  # per-sample cap of the bank's NIS (robust likelihood; = the engine's tracker gate)
CONSISTENCY_P = 1e-4  # the winning hypothesis must pass χ²(3K) at this tail probability

_THR = [np.zeros(0)]  # the table of consistency_thresholds, shared by every bank of the process


def consistency_thresholds(k_max: int) -> np.ndarray:
    """The table thr with thr[k] = chi2_isf(CONSISTENCY_P, 3k) for k ≥ 1 (thr[0] = 0) and at
    least k_max + 1 entries: the decision's consistency test by tracker count (the compiled test
    reads it too). One table per process, grown by doubling (a pure function of k)."""
    thr = _THR[0]
    if thr.shape[0] <= k_max:
        new = np.empty(max(2 * thr.shape[0], k_max + 1024))
        new[:thr.shape[0]] = thr
        for k in range(thr.shape[0], new.shape[0]):
            new[k] = chi2_isf(CONSISTENCY_P, 3 * k) if k > 0 else 0.0
        _THR[0] = thr = new
    return thr


class HypothesisBank:
    """The bank of one alarm, started from the engine snapshot ``snap`` (radical_rt.fdi.monitor.Snapshot).

    State (nh = n_gyro + 1 hypotheses, row h; npar = ns − 3 considered parameters): ``q`` (nh, 4)
    q_body_from_inertial, ``omega`` (nh, 3) [rad/s, body], ``Ptt`` (nh, 3, 3) [rad²], ``Ptp``
    (nh, 3, npar), ``Ppp`` (npar, npar) the snapshot's parameter covariance, ``ll`` (nh,) the
    robust log-likelihood, ``nis`` (nh,) the capped NIS sums, ``k`` tracker samples processed,
    ``t_last`` [s] the last gyro sample propagated, ``trk_seq`` the last tracker sequence number
    processed. ``nis_k``, ``logdet_k`` (nh,) hold the last tracker sample's NIS and ln det S.
    """

    #: the engine's compiled release may run this bank (kernel_args; FaultMonitor.kernel_bank)
    in_release = True

    def __init__(self, eng, snap, t_alarm: float) -> None:
        n, npar = eng.n_gyro, eng.ns - 3
        self.snap, self.t_alarm = snap, t_alarm
        self.gyros: list[int | None] = [None] + list(range(n))
        self._names = ["all"] + [f"ex{g}" for g in range(n)]  # the hypotheses in summaries
        self.masks = np.zeros((n + 1, n), np.bool_)
        self.masks[1:] = np.eye(n, dtype=np.bool_)
        nh = n + 1
        self.xp = snap.xp.copy()
        self.A, self.Minv, self.Gp = np.zeros((3, n)), np.eye(3), np.zeros((3, n))
        N = snap.N.copy()
        refresh_axes(self.xp, eng.geo.W, eng.geo.U, eng.geo.V, snap.N.copy(), self.A, self.Minv,
                     self.Gp, N)
        self.N_none = np.zeros((n, 0))
        P = np.empty((eng.ns, eng.ns))
        ud.ud_to_cov(snap.U, snap.d, P)
        self.Ppp = np.ascontiguousarray(P[3:, 3:])
        self.Ptt = np.repeat(P[None, :3, :3], nh, axis=0)
        self.Ptp = np.repeat(P[None, :3, 3:], nh, axis=0)
        self.q = np.repeat(snap.q[None, :], nh, axis=0)
        self.omega = np.repeat(snap.omega[None, :], nh, axis=0)
        self.ll = np.zeros(nh)  # log-likelihood (robust, up to a common constant)
        self.nis = np.zeros(nh)  # capped NIS sums
        self.nis_k, self.logdet_k = np.zeros(nh), np.zeros(nh)
        self.k = 0  # tracker samples processed
        self.t_last = snap.t  # last gyro sample propagated
        self.trk_seq = snap.trk_seq
        self.undetermined = np.zeros(nh, np.int64)
        lay = eng.layout
        self.phi_col = lay["phi2"].start - 3
        self.lat_col = lay["lat"].start - 3 if "lat" in lay else -1
        self.phi = self.xp[self.phi_col:self.phi_col + 3].copy()
        self.tau = float(self.xp[self.lat_col]) if self.lat_col >= 0 else 0.0
        self.tlast = np.array([snap.t])  # last gyro sample propagated [s] (the kernels' copy)
        # transition of each hypothesis since its covariance was last brought up to date
        self.Phi_aa = np.repeat(np.eye(3)[None], nh, axis=0)
        self.Phi_ap, self.Q_aa = np.zeros((nh, 3, npar)), np.zeros((nh, 3, 3))
        self._pw = (np.zeros((2, n)), np.zeros((2, n)), np.zeros(4, np.int64), np.zeros(3),
                    np.zeros(3))  # propagate_window work
        self._w33, self._w3p, self._w4 = np.zeros((12, 3, 3)), np.zeros((3, 3, npar)), np.zeros((4, 4))
        self._sig_src, self._sig = None, np.zeros(3)
        self._decided: tuple = (None, None)  # ((k, llr_min), decision) of the last decision
        self.bad_s = 0  # hypothesis-samples whose S was not positive definite (ll = −inf)
        self._thr = consistency_thresholds(0)  # (the table the kernel tuple holds)
        self._bi, self._bf = np.zeros(8, np.int64), np.zeros(5)
        self._kargs: tuple | None = None
        self._kkey: tuple | None = None  # (si, llr_min) of the controls last written

    #: what changes as the bank runs (the rest derives from the snapshot): checkpoints
    STATE_ARRAYS = ("q", "omega", "Ptt", "Ptp", "Ppp", "ll", "nis", "nis_k", "logdet_k",
                    "undetermined", "tlast", "Phi_aa", "Phi_ap", "Q_aa")
    STATE_SCALARS = ("k", "t_last", "trk_seq", "bad_s")

    def get_state(self) -> dict[str, Any]:
        """The running state (copies; the snapshot and t_alarm are the caller's)."""
        out: dict[str, Any] = {k: getattr(self, k).copy() for k in self.STATE_ARRAYS}
        out.update({k: getattr(self, k) for k in self.STATE_SCALARS})
        return out

    def set_state(self, st: dict[str, Any]) -> None:
        """Put :meth:`get_state` values into a bank built from the same snapshot (shapes and
        dtypes checked by the caller against this bank's own)."""
        for k in self.STATE_ARRAYS:
            getattr(self, k)[...] = st[k]
        for k in self.STATE_SCALARS:
            setattr(self, k, st[k])
        self._decided = (None, None)

    # ------------------------------------------------------------------ kernels
    def _cal(self, eng) -> tuple:
        return (self.masks, self.xp, self.A, eng.geo.W, eng.geo.U, eng.geo.V, self.Minv, self.Gp,
                self.N_none, eng.si.arw_var_per_s, self.q, self.omega, self.tlast,
                self.undetermined, self.Phi_aa, self.Phi_ap, self.Q_aa)

    def propagate_to(self, eng, buf, t_end: float) -> None:
        """All hypotheses through the buffered gyro samples with t_last < t ≤ t_end (one call;
        the covariance follows at the next tracker sample or :meth:`final_state`)."""
        f, st, br, i0, end = buf.blocks()
        if end > i0 and bank_propagate(f, st, br, i0, end, t_end, *self._cal(eng), *self._pw):
            self.t_last = float(self.tlast[0])

    def update_trackers(self, eng, gbuf, batch: list[tuple]) -> None:
        """Valid tracker samples (seq, epoch [s], ST j, measured q_st_from_inertial (4,), stars),
        in epoch order, for every hypothesis, each after the gyro samples up to its epoch (one
        kernel call for the whole batch)."""
        si = eng.si
        if si.st_sigma is not self._sig_src:
            self._sig_src, self._sig = si.st_sigma, np.asarray(si.st_sigma, dtype=np.float64)
        m = len(batch)
        epoch, q_meas = np.empty(m), np.empty((m, 4))
        n_stars, st2 = np.empty(m, np.int64), np.empty(m, np.bool_)
        for i, (_seq, t_epoch, j, q, n) in enumerate(batch):
            epoch[i], q_meas[i], n_stars[i], st2[i] = t_epoch, q, n, j == 2
        f, st, br, i0, end = gbuf.blocks()
        geo = eng.geo
        self.bad_s += bank_run(
            f, st, br, i0, end, q_meas, n_stars, epoch, st2,
            np.ascontiguousarray(geo.R_st1_from_body), np.ascontiguousarray(geo.R_st2_from_body_nom),
            self.phi, self.phi_col, self.lat_col, self.tau, self._sig, si.st_ref_stars,
            eng.timing_sigma(), NIS_CAP, *self._cal(eng), self.Ptt, self.Ptp, self.Ppp, self.ll,
            self.nis, self.nis_k, self.logdet_k, *self._pw, self._w33, self._w3p, self._w4)
        self.t_last = float(self.tlast[0])
        self.k += m
        self.trk_seq = batch[-1][0]

    def final_state(self, eng, gbuf, h: int) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                         np.ndarray]:
        """(q (4,), omega (3,), Ptt (3, 3), Ptp (3, npar)) of hypothesis h at the engine's last
        propagated sample: the gyro samples since the last tracker sample and the pending
        transition applied (the monitor's hand-over at an isolation)."""
        self.propagate_to(eng, gbuf, eng.t)
        bank_flush(self.Phi_aa, self.Phi_ap, self.Q_aa, self.Ptt, self.Ptp, self.Ppp,
                   self._w3p[0], self._w3p[1], self._w33[10])
        return self.q[h], self.omega[h], self.Ptt[h], self.Ptp[h]

    # ------------------------------------------------------------------ inside the compiled release
    def kernel_args(self, eng, gbuf, hist_end: int, rows: int, llr_min: float) -> tuple:
        """The bank's buffers (bfb, bib, bbb, blay) for the compiled release, which runs the bank
        on its valid tracker samples (radical_rt.engine.loop) with the tuple bk of
        :func:`radical_rt.fdi.fdi_bank.bank_sample` rebuilt from them and from the gyro history's
        blocks (:mod:`radical_rt.fdi.fdi_bank_pack`; rows gbuf.i0..hist_end−1 in use by then, the
        release appends its samples first): the stacked state and work arrays, phi, st_sigma,
        the consistency thresholds for up to ``rows`` more samples, and the controls bi, bf
        (BI_*, BF_*; BI_STEPS, BI_BAD zeroed). Only valid while the bank is caught up with the
        monitor's tracker buffer."""
        si = eng.si
        if si.st_sigma is not self._sig_src:
            self._sig_src, self._sig = si.st_sigma, np.asarray(si.st_sigma, dtype=np.float64)
        if self._thr.shape[0] <= self.k + rows:
            self._thr, self._kargs = consistency_thresholds(self.k + rows), None
        i0 = gbuf.blocks()[3]
        kargs = self._kargs
        if kargs is None or self._sig is not self._packed_sig:
            kargs = self._pack()
        bi, bf = self._bi, self._bf
        bi[BI_ON], bi[BI_I0], bi[BI_END], bi[BI_K] = 1, i0, hist_end, self.k
        bi[BI_STEPS] = bi[BI_BAD] = 0
        kk = self._kkey  # the rest changes only with the parameters (a new si) or llr_min
        if kk is None or kk[0] is not si or kk[1] != llr_min:
            self._kkey = (si, llr_min)
            bi[BI_PHI_COL], bi[BI_LAT_COL] = self.phi_col, self.lat_col
            bf[BF_TAU], bf[BF_REF_STARS], bf[BF_GATE] = self.tau, si.st_ref_stars, NIS_CAP
            bf[BF_LLR_MIN], bf[BF_ARW] = llr_min, si.arw_var_per_s
        return kargs

    def _pack(self) -> tuple:
        """Move the arrays of the release's tuple into new flat buffers (:func:`pack_bank`) and
        keep the views of them as the bank's arrays (copies, e.g. a checkpoint's, are packed again
        at their first use: :meth:`__getstate__`). Returns the buffers."""
        pw = self._pw
        kargs, v = pack_bank({
            "masks": self.masks, "xp": self.xp, "A": self.A, "Minv": self.Minv, "Gp": self.Gp,
            "N_none": self.N_none, "q": self.q, "omega": self.omega, "tlast": self.tlast,
            "undetermined": self.undetermined, "Phi_aa": self.Phi_aa, "Phi_ap": self.Phi_ap,
            "Q_aa": self.Q_aa, "Ptt": self.Ptt, "Ptp": self.Ptp, "Ppp": self.Ppp, "ll": self.ll,
            "nis": self.nis, "nis_k": self.nis_k, "logdet_k": self.logdet_k, "par_y": pw[0],
            "par_t": pw[1], "acc_i": pw[2], "acc_f": pw[3], "th_acc": pw[4], "W33": self._w33,
            "W3p": self._w3p, "W4": self._w4, "phi": self.phi, "st_sigma": self._sig,
            "thr": self._thr, "bi": self._bi, "bf": self._bf})
        for name in ("masks", "xp", "A", "Minv", "Gp", "N_none", "q", "omega", "tlast",
                     "undetermined", "Phi_aa", "Phi_ap", "Q_aa", "Ptt", "Ptp", "Ppp", "ll", "nis",
                     "nis_k", "logdet_k", "phi"):
            setattr(self, name, v[name])
        self._pw = (v["par_y"], v["par_t"], v["acc_i"], v["acc_f"], v["th_acc"])
        self._w33, self._w3p, self._w4 = v["W33"], v["W3p"], v["W4"]
        self._sig, self._thr, self._bi, self._bf = v["st_sigma"], v["thr"], v["bi"], v["bf"]
        self._packed_sig, self._kargs = self._sig, kargs
        return kargs

    _packed_sig: np.ndarray | None = None  # the st_sigma view of the packed buffers

    def __getstate__(self) -> dict[str, Any]:
        """Copies (copy.deepcopy, pickle) copy each array on its own: they are packed into
        buffers of their own at their first use in a release."""
        state = self.__dict__.copy()
        state["_kargs"] = state["_packed_sig"] = None
        return state

    def kernel_done(self) -> int:
        """Take back what the compiled release did with :meth:`kernel_args`' tuple: the tracker
        samples it processed (k, trk_seq: the monitor's next samples, which the engine hands to
        it afterwards), t_last and the bad-S count. Returns the number of samples."""
        bi = self._bi
        steps = int(bi[BI_STEPS])
        bi[BI_ON] = 0
        if steps:
            self.k += steps
            self.trk_seq += steps
            self.bad_s += int(bi[BI_BAD])
            self.t_last = float(self.tlast[0])
        bi[BI_STEPS] = bi[BI_BAD] = 0
        return steps

    # ------------------------------------------------------------------ driver and decision
    def advance(self, eng, gbuf, trk: deque, t_upto: float) -> None:
        """Process the buffered trackers (seq > last) with epoch ≤ t_upto, each after the gyro
        samples up to its epoch, in the engine's order. The gyro samples after the last tracker
        sample wait for the next one (or :meth:`final_state`): they cannot change the
        log-likelihoods, and the propagation composes the same transition whatever the runs
        (sample by sample), so only the covariance's rounding depends on where runs end."""
        # sequence numbers are consecutive in the deque: index the first one not yet processed
        k = max(0, self.trk_seq + 1 - trk[0][0]) if trk else 0
        batch = []
        while k < len(trk) and trk[k][1] <= t_upto:
            batch.append(trk[k])
            k += 1
        if batch:
            self.update_trackers(eng, gbuf, batch)

    def decision(self, llr_min: float) -> tuple[str, int | None, float]:
        """("isolate", gyro, margin), ("none", None, margin) when H0 wins, or ("wait", …)."""
        key = (self.k, llr_min)
        if key == self._decided[0]:
            return self._decided[1]  # ll and nis change only with a tracker sample
        self._decided = (key, self._decide(llr_min))
        return self._decided[1]

    def _decide(self, llr_min: float) -> tuple[str, int | None, float]:
        if self.k == 0:
            return "wait", None, 0.0
        code, best, margin = decide(self.ll, self.nis, consistency_thresholds(self.k), self.k,
                                    llr_min)
        if code == 0:
            return "wait", None, margin
        gyro = self.gyros[best]
        return ("none" if gyro is None else "isolate"), gyro, margin

    def summary(self) -> dict[str, Any]:
        best = float(self.ll.max()) if self.k else 0.0
        ll, nis, k = self.ll.tolist(), self.nis.tolist(), max(self.k, 1)
        names = self._names
        return {"t_start": self.snap.t, "trackers": self.k,
                "llr": {name: x - best for name, x in zip(names, ll, strict=True)},
                "nis_mean": {name: x / k for name, x in zip(names, nis, strict=True)},
                "undetermined": self.undetermined.tolist()}


def idle_kernel_args() -> tuple:
    """A stand-in for :meth:`HypothesisBank.kernel_args` when no bank runs in the compiled
    release: the buffers of empty arrays of the kinds BK_SLOTS declares, except the controls
    bi (8,) and bf (5,), with BI_ON = 0 (:func:`radical_rt.fdi.fdi_bank_pack.idle_buffers`)."""
    return idle_buffers()


__all__ = ["CONSISTENCY_P", "NIS_CAP", "HypothesisBank", "idle_kernel_args"]
