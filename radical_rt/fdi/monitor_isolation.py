"""The alarm, isolation and reconfiguration steps of the FDI monitor (docs/fdi.md §3–§4).

:class:`IsolationSteps` is a part of :class:`radical_rt.fdi.monitor.FaultMonitor` (a mixin: it
works on the monitor's own state): raising an alarm and starting the hypothesis bank from the
snapshot before the onset estimate, the isolation record with the fault size from the parity
innovations [deg/h], and the reconfiguration handed to the engine (:class:`Reconfiguration`:
calibration and covariance rolled back to the snapshot, attitude from the winning hypothesis).
The detection and the bookkeeping are in :mod:`radical_rt.fdi.monitor`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from radical_rt.contract.conventions import DEG_PER_HR, SIRU_PERIOD_S
from radical_rt.contract.flags import GYRO_FAILED, Flag
from radical_rt.fdi.fdi_hypotheses import HypothesisBank
from radical_rt.kernels import ud

ONSET_MARGIN_S = 2.0  # the bank starts from a snapshot at least this long before the onset estimate


class Reconfiguration(NamedTuple):
    """The engine state an isolation hands to ``Engine.apply_isolation``: the UD factors U (ns, ns)
    and d (ns,), the parameters xp (ns − 3,) [internal units], q_body_from_inertial (4,) and the
    body rate omega (3,) [rad/s] of the winning hypothesis, and dt_noise [s], the time since the
    snapshot over which the parameter process noise is added."""

    U: np.ndarray
    d: np.ndarray
    xp: np.ndarray
    q: np.ndarray
    omega: np.ndarray
    dt_noise: float



class IsolationSteps:
    """The alarm → bank → isolation → reconfiguration steps of :class:`radical_rt.fdi.monitor.FaultMonitor`
    (which provides the state they work on: the detector, history, snapshots, bank, alarm records
    and counts, ``bank_type``, ``_p`` and ``_check_gen``)."""

    def _raise_alarm(self, eng, test: str, t_onset: float, nu: float, rho: float) -> None:
        self._check_gen(eng)
        first = self.state != "alarm"
        eng.flags |= Flag.PARITY_ALARM
        self.state = "alarm"
        # The bank starts from the latest snapshot before the onset estimate minus a margin. A CUSUM
        # excursion starts late for a slowly growing fault (only once its mean exceeds k), so
        # there the margin is the excursion's own length.
        margin = ONSET_MARGIN_S
        if test == "cusum":
            margin = max(margin, eng.t - t_onset)
        snap = None
        for s in self.snaps:
            if s.t <= t_onset - margin:
                snap = s
        if snap is None and self.snaps:
            snap = self.snaps[0]
        rec = {"t_alarm": float(eng.t), "test": test, "t_onset_est": float(t_onset),
               "nu": float(nu), "rho": float(rho), "bank": "running" if snap else "no snapshot",
               "t_snapshot": float(snap.t) if snap else None}
        if first:
            self.counts["alarms"] += 1
            self.alarms.append(rec)
            self.alarm = rec
        else:  # a new trigger during an alarm whose bank ended: a fresh bank, same alarm
            self.alarm.update({k: v for k, v in rec.items() if k != "t_alarm"})
        if snap is not None:
            self.bank = self.bank_type(eng, snap, float(eng.t))
            self._t_decided = -math.inf
            self.counts["banks"] += 1

    def _fault_size(self, eng, gyro: int, t_onset: float) -> dict[str, float]:
        """Size of the fault on ``gyro`` from the parity innovations of the sums that started after
        the onset estimate: z ≈ p_i f T (T the sum length)."""
        zs = np.array([z for t0, z in self.parity_log if t0 >= t_onset - 1e-9])
        t_sum = eng.si.parity_window * SIRU_PERIOD_S
        p = float(self.bank.snap.N[gyro, 0])
        if zs.size == 0 or p == 0.0:
            return {}
        return {"rate_mean_deg_hr": float(zs.mean() / (p * t_sum) / DEG_PER_HR),
                "rate_rms_deg_hr": float(np.sqrt(np.mean(zs**2)) / (abs(p) * t_sum) / DEG_PER_HR),
                "sums": int(zs.size)}

    def _isolate(self, eng, gyro: int, margin: float) -> None:
        bank = self.bank
        h = bank.gyros.index(gyro)
        rec = {"gyro": int(gyro), "t_isolated": float(eng.t), "t_alarm": self.alarm["t_alarm"],
               "t_onset_est": self.alarm["t_onset_est"], "test": self.alarm["test"],
               "llr_margin": margin, "t_snapshot": bank.snap.t, "trackers": bank.k,
               "auto_exclude": bool(self._p(eng, "auto_exclude", True)),
               "fault_size": self._fault_size(eng, gyro, self.alarm["t_onset_est"]),
               "bank": bank.summary()}
        self.isolations.append(rec)
        self.counts["isolations"] += 1
        self.alarm["bank"] = f"isolated gyro {gyro}"
        eng.flags |= GYRO_FAILED[gyro]
        self.failed_by_fdi.add(int(gyro))
        self.bank = None
        if rec["auto_exclude"] and eng.n_gyro - int(eng.excluded.sum()) - 1 >= 3:
            self._reconfigure(eng, bank, h, gyro)
            eng.flags &= ~int(Flag.PARITY_ALARM)
            self.state = "three-gyro"
        else:  # flagged only: PARITY_ALARM stays, no new bank until the operator acts
            self.flagged_only.add(int(gyro))
            self.state = "flagged"

    def _reconfigure(self, eng, bank: HypothesisBank, h: int, gyro: int) -> None:
        """Exclude ``gyro``; calibration and its covariance back to the pre-fault snapshot (plus the
        parameter process noise since), attitude and cross-covariance from the winning filter.
        The FDI computes the state; the engine applies it (``Engine.apply_isolation``)."""
        ns = eng.ns
        P = np.empty((ns, ns))
        q, omega, Ptt, Ptp = bank.final_state(eng, self.gbuf, h)
        P[:3, :3] = Ptt
        P[:3, 3:] = Ptp
        P[3:, :3] = Ptp.T
        P[3:, 3:] = bank.Ppp
        U, d = np.eye(ns), np.ones(ns)
        if ud.factor_ud(P, U, d) == 0 and np.all(d > 0):
            state = Reconfiguration(U=U, d=d, xp=bank.xp, q=q, omega=omega,
                                    dt_noise=max(eng.t - bank.snap.t, 0.0))
        else:  # keep the engine's own covariance, restart the attitude from the trackers
            state = None
        eng.apply_isolation(gyro, state)
        self.snaps.clear()  # pre-reconfiguration snapshots describe four gyros

    def compile_bank(self, eng) -> bool:
        """Run a throw-away bank from the latest snapshot over the buffered samples, so that its
        kernels are compiled (or loaded from the cache) before the first alarm (the node's
        start-up warm-up). Changes nothing; False without a snapshot or tracker samples."""
        if not self.snaps or not self.trk:
            return False
        bank = self.bank_type(eng, self.snaps[0], float(eng.t))
        bank.advance(eng, self.gbuf, self.trk, float(eng.t))
        bank.final_state(eng, self.gbuf, 0)
        bank.decision(self.llr_threshold(eng))
        return bank.k > 0
