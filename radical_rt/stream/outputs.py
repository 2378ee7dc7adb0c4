"""The output side of the stream processor: flags, counters, the fault, diag and telemetry
messages and their schedule.

:class:`StreamOutputs` is a part of :class:`radical_rt.stream.processor.StreamProcessor` (a mixin:
it works on the processor's own state — engine, clock, guards, queues, stream log). At every
window close the engine calls :meth:`StreamOutputs.on_window` (a hook of
:mod:`radical_rt.engine.hooks`): a ``fault`` message when the published flags changed, the
window-triggered packets and the ``diag`` that are due (CONTRACT §3); :meth:`StreamOutputs.wake`
tells the engine's compiled loop from which event time [s] / engine time [s] that hook has work.
Sample-triggered packets are built after each SIRU message with the attitude predicted to the
newest sample (:meth:`StreamOutputs.now`). Outputs are queued and collected with
:meth:`StreamOutputs.take_outputs` as (key, message) pairs.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from radical_rt.contract.flags import Flag, flag_names
from radical_rt.engine.gyro_queue import predict_pending
from radical_rt.kernels.propagate import sample_work
from radical_rt.stream.telemetry import PacketSpec, build, read_field

_CLOCK_ANOMALY, _INPUT_REJECTED = int(Flag.CLOCK_ANOMALY), int(Flag.INPUT_REJECTED)


class StreamOutputs:
    """Flags, counters and the output messages of :class:`radical_rt.stream.processor.StreamProcessor`
    (which provides the state they read: ``engine``, ``clock``, ``gyro_q``, ``streams``, the
    guards, the reject record and the output queue ``_out``)."""

    # ---------------------------------------------------------------- outputs
    @property
    def flags(self) -> int:
        f = int(self.engine.flags)
        if self.clock.anomaly:
            f |= _CLOCK_ANOMALY
        if self.engine.t - self.last_reject_t <= self.reject_hold_s or self.t_max == self.last_reject_t:
            f |= _INPUT_REJECTED
        return f | self._guard_flags()

    def flag_names(self) -> list[str]:
        return flag_names(self.flags)

    def counters(self) -> dict[str, int]:
        """Summary counters of CONTRACT §5 plus engine and input details."""
        c, e = self.clock.counters, self.engine.counters
        out = {"siru_samples": int(c.get("samples", 0)), "siru_repeated": int(c.get("repeated", 0)),
               "siru_missing": int(c.get("missing", 0)), "siru_bridged": int(c.get("bridged", 0)),
               "st1_used": e["st1_used"], "st1_edited": e["st1_edited"],
               "st2_used": e["st2_used"], "st2_edited": e["st2_edited"],
               "parity_used": e["parity_used"], "parity_edited": e["parity_edited"],
               "input_rejected": int(sum(self.rejected.values())), "late_dropped": self.late_dropped}
        out.update(self._guard_counters())
        return out

    # ---------------------------------------------------------------- output schedule (engine hooks)
    def wake(self) -> tuple[float, float]:
        """For the engine's compiled loop: the event time and the engine time from which
        :meth:`on_window` has work while the engine's flags stay the same (−inf: now). Earlier
        is always safe (the hook then finds nothing to do)."""
        if self.flags != self._last_flags:
            return -math.inf, -math.inf
        wake_t = self.packet_wake
        if wake_t is None:
            wake_t = self.packet_wake = self._next_packet_t()
        wake_e = self._guard_wake()  # a held flag's hold ends
        if self._last_flags & _INPUT_REJECTED and self.t_max != self.last_reject_t:
            wake_e = min(wake_e, self.last_reject_t + self.reject_hold_s - 1e-6)  # the hold ends
        return wake_t, wake_e

    def _next_packet_t(self) -> float:
        """Event time of the next window packet or diag (−inf: a decimated packet, which counts
        every window close)."""
        wake_t = self.diag.next_t
        for spec in self.packets.values():
            if spec.trigger == "window":
                if spec.decimation is not None:
                    return -math.inf
                wake_t = min(wake_t, spec.next_t)
        return wake_t

    # kept until the schedule can change: on_window, end_stream, new packets
    packet_wake: float | None = None

    @property
    def packets(self) -> dict[str, PacketSpec]:
        """The telemetry packets {small|medium|large: PacketSpec}; assign a new map to change them
        (set_packets, checkpoint restore)."""
        return self._packets

    @packets.setter
    def packets(self, specs: dict[str, PacketSpec]) -> None:
        self._packets = specs
        self.packet_wake = None
        # the sample-triggered packets and their keys (built after each SIRU message)
        self._sample_specs = [(f"tlm/{n}", s) for n, s in specs.items() if s.trigger == "sample"]
        self._sample_packets = bool(self._sample_specs)

    def on_window(self, t: float) -> None:
        """After a window close at event time t [s]: a fault message when the flags changed,
        the window packets and the diag that are due."""
        self.packet_wake = None  # the packets' due() below moves their schedule
        memo: dict[str, Any] = {}  # the packets and the diag of this close read one state
        flags = self.flags
        if flags != self._last_flags:
            self._emit_fault(t)  # (publishing may end a held flag: the field is read again)
        else:
            memo["flags"] = flags  # the packets' flags field, int(self.flags)
        for spec in self.packets.values():
            if spec.trigger == "window" and spec.due(t):
                self._out.append((f"tlm/{spec.name}", build(spec, self, memo=memo)))
        if self.diag.due(t):
            self._out.append(("diag", self.diag_message(memo)))

    def _emit_fault(self, t: float) -> None:
        flags, prev = self.flags, self._last_flags or 0
        self._out.append(("fault", {"v": 1, "stream": self.streams.index, "t": t, "flags": flags,
                                    "set": flag_names(flags & ~prev),
                                    "cleared": flag_names(prev & ~flags),
                                    "detail": self._fault_detail()}))
        self._last_flags = flags
        self._guard_published(flags, t)

    def _sample_outputs(self) -> None:
        """Sample-triggered packets due at the newest sample time, with the predicted attitude
        (made by the release kernel itself when the release it just ran ended there, else by
        :meth:`now`)."""
        now = None
        for key, spec in self._sample_specs:
            if spec.due(self.t_now):
                if now is None:
                    pred = self._pred
                    p = pred.tolist()  # (one read: flag, t, q (4,), ω (3,))
                    now = _now_fields(p[1], p[2:6], p[6:9]) if p[0] == 2.0 else self.now()
                self._out.append((key, build(spec, self, now)))

    def now(self) -> dict[str, Any]:
        """Packet fields ``t``, ``q_body_from_inertial``, ``omega_body`` at the newest sample:
        predicted through the samples not yet given to the filter and through the read the clock
        holds back (taken as the next sample, one estimated period later, unless it repeats the
        last one). Other packet fields keep the filter's current state."""
        e = self.engine
        q, omega = e.q.copy(), e.omega.copy()
        if not e.att_valid:
            return _now_fields(e.t, q.tolist(), omega.tolist())
        gq = self.gyro_q
        # the newest read, held back by the clock's look-ahead, taken as the next sample
        clock_I, clock_F = self.clock.state_arrays()
        work = self._pred_work
        if work is None:
            work = self._pred_work = sample_work(e.n_gyro)
        t = predict_pending(gq.dtheta, gq.dt, gq.status, gq.head, gq.end, self.t_now, clock_I,
                            clock_F, e.excluded, e.xp, e.A, e.Gp, q, omega, work)
        return _now_fields(t, q.tolist(), omega.tolist())

    _pred_work = None  # the prediction's work arrays (kernels.propagate.SampleWork), made once

    def _fault_detail(self) -> dict[str, Any]:
        d: dict[str, Any] = {"mode": self.engine.mode}
        if self.rejected:
            d["rejected"] = dict(self.rejected)
            d["last_reject"] = getattr(self, "last_reject", "")
        if self.engine.last_numeric:
            d["numeric"] = self.engine.last_numeric
        if self.engine.fdi is not None:  # parity FDI state, alarm and last isolation (docs/fdi.md)
            d["fdi"] = self.engine.fdi.detail()
        return d

    def diag_message(self, memo: dict[str, Any] | None = None) -> dict[str, Any]:
        """The diag message (CONTRACT §3); ``memo``: packet fields already read from this state
        (:func:`radical_rt.stream.telemetry.build`)."""
        e = self.engine
        memo = {} if memo is None else memo

        def field(name: str) -> Any:
            return read_field(name, self, memo)

        return {"v": 1, "stream": self.streams.index, "stream_info": self.streams.info(),
                "t": e.t, "flags": field("flags"), "mode": e.mode,
                "residuals": field("residuals"), "counters": field("counters"),
                "engine_counters": self._engine_counters(), "rejected": dict(self.rejected),
                "clock": field("clock"), "temps": dict(self.temps),
                "latency": field("latency"), "fdi": field("fdi"),
                "ud": _d_range(e.d),
                "excitation": e.excitation.report() if e.excitation is not None else None}

    def _engine_counters(self) -> dict[str, int]:
        """``dict(sorted(engine.counters.items()))``, the key order kept while the keys (in
        their insertion order) stay the same."""
        c = self.engine.counters
        keys = tuple(c)
        order = self._counter_order
        if order is None or order[0] != keys:
            order = self._counter_order = (keys, sorted(keys))
        return {k: c[k] for k in order[1]}

    _counter_order: tuple[tuple[str, ...], list[str]] | None = None

    def take_outputs(self) -> list[tuple[str, dict[str, Any]]]:
        out, self._out = self._out, []
        return out



def _d_range(d: np.ndarray) -> dict[str, float]:
    """diag's ``ud`` map {d_min, d_max} of the UD diagonal d (ns,): ``float(d.min())`` and
    ``float(d.max())``, taken on a list (a NumPy reduction costs tens of µs in the hook, its code
    cold after the compiled release); NumPy's where a NaN or a zero (signed zeros) could make
    the two differ."""
    v = d.tolist()
    lo, hi = min(v), max(v)
    if lo == 0.0 or hi == 0.0 or math.isnan(sum(v)):
        lo, hi = float(d.min()), float(d.max())
    return {"d_min": lo, "d_max": hi}


def _now_fields(t: float, q: list[float], omega: list[float]) -> dict[str, Any]:
    """Packet fields that a sample-triggered packet takes from the prediction (t [s], q (4,)
    scalar-last, ω (3,) [rad/s], as plain floats)."""
    return {"t": t, "q_body_from_inertial": q, "omega_body": omega}
