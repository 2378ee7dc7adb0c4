"""Checkpoint state and the diagnostic detail of the FDI monitor.

:class:`MonitorState` is a part of :class:`radical_rt.fdi.monitor.FaultMonitor` (a mixin: it works
on the monitor's own state): :meth:`MonitorState.get_state` / :meth:`MonitorState.set_state`, the
plain-type state a checkpoint carries between two hooks (encoded and validated by
:mod:`radical_rt.io.ckpt_fdi`), and :meth:`MonitorState.detail`, the ``fault`` message detail.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np

from radical_rt.fdi.fdi_history import Snapshot


class MonitorState:
    """Checkpoint get/set and the detail of :class:`radical_rt.fdi.monitor.FaultMonitor` (which
    provides the state: scalars, history, snapshots, detector, bank and records)."""

    # ------------------------------------------------------------------ checkpoints
    _SCALARS = ("state", "last_nu", "last_rho", "_next_check", "_sum_seen", "_t_decided",
                "trk_seq")

    def get_state(self, history: bool = True) -> dict[str, Any]:
        """Everything the monitor carries between two hooks (numpy arrays and plain values;
        radical_rt.io.ckpt_fdi encodes and validates it): a resume continues an alarm in progress
        with the same history, snapshots and bank. ``history=False`` leaves out the gyro and
        tracker history, the snapshots and the bank (up to 600 s of samples, megabytes): what
        a new stream starts without anyway (a warm start voids them), so a state only ever
        restored as a new stream (a fleet's periodic replica) need not carry them."""
        b = self.bank if history else None
        gbuf = self.gbuf.get_state(rows=history)
        return {**{k: getattr(self, k) for k in self._SCALARS},
                "gen": None if self.gen is None else list(self.gen), "alarm": self.alarm,
                "alarm_is_last": bool(self.alarms) and self.alarm is self.alarms[-1],
                "alarms": self.alarms, "isolations": self.isolations,
                "parity_log": np.array(self.parity_log, np.float64).reshape(-1, 2),
                "failed": sorted(self.failed_by_fdi), "flagged_only": sorted(self.flagged_only),
                "counts": dict(self.counts), "gbuf": gbuf,
                "trk": self.trk.get_state(rows=history),
                "snaps": [vars(s) for s in self.snaps] if history else [],
                "det": None if self.det is None else self.det.get_state(),
                "bank": None if b is None else {"snap": vars(b.snap), "t_alarm": b.t_alarm,
                                                **b.get_state()}}

    def set_state(self, eng, st: dict[str, Any]) -> None:
        """Put a validated :meth:`get_state` back (after the engine's own state)."""
        for k in self._SCALARS:
            setattr(self, k, st[k])
        self.gen = None if st["gen"] is None else tuple(st["gen"])
        self.alarms, self.isolations = list(st["alarms"]), list(st["isolations"])
        self.alarm = self.alarms[-1] if st["alarm_is_last"] else st["alarm"]
        self.parity_log = deque((float(t0), float(z)) for t0, z in st["parity_log"])
        self.failed_by_fdi, self.flagged_only = set(st["failed"]), set(st["flagged_only"])
        self.counts.update(st["counts"])
        self.gbuf.set_state(st["gbuf"])
        self.trk.set_state(st["trk"])
        self.snaps = deque(Snapshot(**s) for s in st["snaps"])
        self._th_key, self.det = None, None
        if st["det"] is not None:
            self.detector(eng).set_state(st["det"])
        self.bank = None
        if st["bank"] is not None:
            bs = dict(st["bank"])
            self.bank = self.bank_type(eng, Snapshot(**bs.pop("snap")), bs.pop("t_alarm"))
            self.bank.set_state(bs)

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Copies (copy.deepcopy, pickle) copy each array on its own: the detector's statistics
        and configuration are views of the array the engine's loop updates (``fq``,
        radical_rt.fdi.fdi_quiet), and become views of the copy's array again."""
        self.__dict__.update(state)
        self._bind_detector()

    # ------------------------------------------------------------------ outputs
    def detail(self) -> dict[str, Any]:
        """Plain-type state for the ``fault`` message detail and diagnostics."""
        d: dict[str, Any] = {"state": self.state, "failed": sorted(self.failed_by_fdi)}
        if self.det is not None:
            d.update({"nu_last": _f(self.last_nu), "rho_last": _f(self.last_rho),
                      "cusum": [self.det.s_pos, self.det.s_neg], "guarded": bool(self.det.guarded),
                      "thresholds": {"inst": self.det.th.t_inst, "persist": self.det.th.t_persist,
                                     "cusum_h": self.det.th.cusum_h}})
        if self.alarm is not None:
            d["alarm"] = dict(self.alarm)
        if self.bank is not None:
            d["bank"] = self.bank.summary()
        if self.isolations:
            last = self.isolations[-1]
            d["last_isolation"] = {k: last[k] for k in (
                "gyro", "t_onset_est", "t_alarm", "t_isolated", "test", "llr_margin",
                "fault_size")}
        d["counts"] = dict(self.counts)
        return d



def _f(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None
