"""The event pipeline shared by both shells: decode → clock → order by epoch → engine → packets.

:class:`StreamProcessor` takes input messages in arrival order (the batch shell feeds an archive in
``log_time`` order, the node feeds what Zenoh delivers) and releases events to the engine in epoch
order: gyro samples at their reconstructed time, tracker samples at ``t_bus − latency``. A sample is
released once the watermark ``max(t_bus seen) − latency − reorder_slack`` has passed it, so both
shells present the engine with the same event sequence and produce bit-identical results.
Tracker samples older than what was already released are counted (``late_dropped``) and dropped.
Outputs (fault, diag, window-triggered telemetry) are produced at window closes (deterministic
points); sample-triggered telemetry (the low-latency ``tlm/small`` default) right after a SIRU
message is taken in, with the attitude predicted from the filter's estimate through the samples
still held back (:func:`radical_rt.propagate.predict_attitude`), so its latency is the processing
time of one message, not the tracker latency.
"""

from __future__ import annotations

import heapq
import math
from collections import defaultdict
from typing import Any

import numpy as np

from .clock import ClockConfig, SiruClock
from .filter import Engine
from .flags import Flag, flag_names
from .gyro_queue import GyroQueue, predict_pending
from .packets import InputError, decode_siru, decode_temp, decode_tracker, unpack
from .siru_wire import SiruWire
from .telemetry import PacketSpec, build, default_packets, read_field

INPUT_TOPICS = ("siru", "st1", "st2", "temp")
_CLOCK_ANOMALY, _INPUT_REJECTED = int(Flag.CLOCK_ANOMALY), int(Flag.INPUT_REJECTED)


class StreamProcessor:
    """Engine + clock + reorder buffer + output scheduling for one vehicle."""

    def __init__(self, engine: Engine, clock: SiruClock | None = None,
                 packets: dict[str, PacketSpec] | None = None, reorder_slack_s: float = 0.05,
                 diag_period_s: float = 1.0, reject_hold_s: float = 1.0) -> None:
        self.engine = engine
        self.clock = clock or SiruClock(ClockConfig(), n_gyro=engine.n_gyro)
        self.packets = packets or default_packets()
        self.reorder_slack_s, self.reject_hold_s = reorder_slack_s, reject_hold_s
        self.diag = PacketSpec("diag", [], period_s=diag_period_s)
        self.rejected: dict[str, int] = defaultdict(int)
        self.late_dropped = 0
        self.temps: dict[str, float] = {}
        self.last_reject_t = -math.inf
        self._out: list[tuple[str, dict[str, Any]]] = []
        self._last_flags = None
        self._gq = GyroQueue(engine.n_gyro)
        self._wire = SiruWire(engine.n_gyro)  # compiled decoding of plain siru messages
        self._begin_stream()
        engine.listener = self._on_window
        engine.wake_source = self._wake
        # the clock's reconstruction uncertainty enters the tracker noise as (ω̂·σ_t)²
        engine.timing_sigma_source = lambda: self.clock.tag_error_sigma_s

    # ---------------------------------------------------------------- input side
    def _begin_stream(self) -> None:
        self.t_max = -math.inf
        self.last_t: dict[str, float] = {}
        self.released_t = -math.inf
        self.t_now = -math.inf  # newest reconstructed gyro sample time taken in [s]
        self._new_sample = False
        self._gq.clear()
        self._trk: list[tuple[float, int, int, np.ndarray, int, bool]] = []
        self._seq = 0

    def feed(self, topic: str, payload: bytes | dict) -> list[tuple[str, dict[str, Any]]]:
        """Take one input message (topic without the leading slash); return outputs produced."""
        try:
            if topic not in INPUT_TOPICS:
                raise InputError("unknown_topic", f"unknown input topic {topic!r}")
            cols = self._wire.decode(payload) if topic == "siru" and isinstance(
                payload, (bytes, bytearray, memoryview)) else None
            msg = unpack(payload) if cols is None else None
            if topic == "siru":
                self._feed_siru(decode_siru(msg, self.engine.n_gyro) if cols is None else cols)
            elif topic == "temp":
                t, values = decode_temp(msg)
                self._check_time(topic, t)
                self.temps.update(values)
            else:
                self._feed_tracker(topic, msg)
        except InputError as exc:
            self._reject(topic, exc)
        self._release(self.t_max - self.engine.si.latency_st_s - self.reorder_slack_s,
                      defer=topic != "siru")
        if self._new_sample:
            self._new_sample = False
            self._sample_outputs()
        return self.take_outputs()

    def _check_time(self, topic: str, t: float) -> None:
        last = self.last_t.get(topic, -math.inf)
        if t == last:
            raise InputError("duplicate", f"{topic} sample at t_bus={t} repeats the previous one")
        if t < last:
            raise InputError("time_backwards", f"{topic} t_bus={t} is before the previous {last}")
        self.last_t[topic] = t
        self.t_max = max(self.t_max, t)

    def _feed_siru(self, cols) -> None:
        """cols: (t_bus (k,) [s], tt (k,) int64, dtheta (k, n) [rad], status (k,) int64), as
        :func:`radical_rt.packets.decode_siru` returns them."""
        t_bus, tt, dth, status = cols
        self._check_time("siru", float(t_bus[0]))
        self.last_t["siru"] = float(t_bus[-1])
        self.t_max = max(self.t_max, float(t_bus[-1]))
        gq = self._gq
        if self.clock.push_into(gq, t_bus, tt, dth, status):
            self.t_now = float(gq.t[gq.end - 1])
            self._new_sample = True

    def _feed_tracker(self, topic: str, msg: dict) -> None:
        t, q, n_stars, valid = decode_tracker(msg)
        self._check_time(topic, t)
        epoch = t - self.engine.si.latency_st_s
        if epoch < self.released_t:
            self.late_dropped += 1
            return
        self._seq += 1
        heapq.heappush(self._trk, (epoch, 1 if topic == "st1" else 2, self._seq, q, n_stars, valid))

    def _reject(self, topic: str, exc: InputError) -> None:
        self.rejected[exc.reason] += 1
        self.last_reject_t = self.t_max
        self.last_reject = f"{topic}: {exc}"

    # ---------------------------------------------------------------- release to the engine
    def _release(self, watermark: float, defer: bool = False) -> None:
        """Give the engine every tracker sample with epoch ≤ watermark and the gyro samples up to
        the watermark, in epoch order (one :meth:`Engine.release`).

        defer: when no tracker sample is due and the gyro samples cannot complete a time-update
        window, leave them in the queue for the next release (they count as released for the
        late-tracker test). Nothing observable happens in such a release — no window closes, so
        no output — and the next release processes the same events in the same order; the
        stream defers on tracker and temperature messages, never before sample outputs."""
        events = []
        while self._trk and self._trk[0][0] <= watermark:
            epoch, j, _seq, q, n_stars, valid = heapq.heappop(self._trk)
            events.append((j, epoch, q, n_stars, valid))
            self.released_t = max(self.released_t, epoch)
        gq, e = self._gq, self.engine
        a, z = gq.head, gq.upto(watermark)
        if z == a and not events:
            return
        if defer and not events and e.acc_i[0] + (z - a) < e.si.prop_window:
            self.released_t = max(self.released_t, float(gq.t[z - 1]))
            return
        gq.head = z  # taken before the engine runs
        arrays = gq.arrays()
        if z > a:
            self.released_t = max(self.released_t, float(gq.t[z - 1]))
        e.release(arrays, a, z, events)

    def end_stream(self, next_start: str | None = "warm") -> list[tuple[str, dict[str, Any]]]:
        """Finish the current stream; prepare the next one with a "warm" (bump) or "cold" start."""
        out = self.clock.flush()
        if len(out.t):
            self._gq.push(out)
        self._release(math.inf)
        if self.engine.att_valid:
            self.engine.flush_parity()
        if next_start is not None:
            self.clock.reset()
            if next_start == "cold":
                self.engine.cold_start()
            else:
                self.engine.warm_start(bump=True)
            self._begin_stream()
            for spec in self.packets.values():
                spec.next_t = -math.inf
            self.diag.next_t = -math.inf
        return self.take_outputs()

    # ---------------------------------------------------------------- outputs
    @property
    def flags(self) -> int:
        f = int(self.engine.flags)
        if self.clock.anomaly:
            f |= _CLOCK_ANOMALY
        if self.engine.t - self.last_reject_t <= self.reject_hold_s or self.t_max == self.last_reject_t:
            f |= _INPUT_REJECTED
        return f

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
        return out

    def _wake(self) -> tuple[float, float]:
        """For the engine's fast path (:mod:`radical_rt.fastpath`): the event time and the engine
        time from which :meth:`_on_window` has work while the engine's flags stay the same
        (−inf: now). Earlier is always safe (the hook then finds nothing to do)."""
        if self.flags != self._last_flags:
            return -math.inf, -math.inf
        wake_t = self.diag.next_t
        for spec in self.packets.values():
            if spec.trigger == "window":
                if spec.decimation is not None:  # counts every window close
                    return -math.inf, -math.inf
                wake_t = min(wake_t, spec.next_t)
        wake_e = math.inf
        if self._last_flags & _INPUT_REJECTED and self.t_max != self.last_reject_t:
            wake_e = self.last_reject_t + self.reject_hold_s - 1e-6  # the hold ends
        return wake_t, wake_e

    def _on_window(self, t: float) -> None:
        flags = self.flags
        if flags != self._last_flags:
            prev = self._last_flags or 0
            self._out.append(("fault", {"v": 1, "t": t, "flags": flags,
                                        "set": flag_names(flags & ~prev),
                                        "cleared": flag_names(prev & ~flags),
                                        "detail": self._fault_detail()}))
            self._last_flags = flags
        memo: dict[str, Any] = {}  # the packets and the diag of this close read one state
        for spec in self.packets.values():
            if spec.trigger == "window" and spec.due(t):
                self._out.append((f"tlm/{spec.name}", build(spec, self, memo=memo)))
        if self.diag.due(t):
            self._out.append(("diag", self.diag_message(memo)))

    def _sample_outputs(self) -> None:
        """Sample-triggered packets due at the newest sample time, with the predicted attitude."""
        now = None
        for spec in self.packets.values():
            if spec.trigger == "sample" and spec.due(self.t_now):
                now = now or self.now()
                self._out.append((f"tlm/{spec.name}", build(spec, self, now)))

    def now(self) -> dict[str, Any]:
        """Packet fields ``t``, ``q_body_from_inertial``, ``omega_body`` at the newest sample:
        predicted through the samples not yet given to the filter and through the read the clock
        holds back (taken as the next sample, one estimated period later, unless it repeats the
        last one). Other packet fields keep the filter's current state."""
        e = self.engine
        q, omega = e.q.copy(), e.omega.copy()
        if not e.att_valid:
            return _now_fields(e.t, q, omega)
        gq = self._gq
        # the newest read, held back by the clock's look-ahead, taken as the next sample
        clock_I, clock_F = self.clock.state_arrays()
        t = predict_pending(gq.dtheta, gq.dt, gq.status, gq.head, gq.end, self.t_now, clock_I,
                            clock_F, e.excluded, e.xp, e.A, e.Gp, q, omega)
        return _now_fields(t, q, omega)

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
        (:func:`radical_rt.telemetry.build`)."""
        e = self.engine
        memo = {} if memo is None else memo

        def field(name: str) -> Any:
            return read_field(name, self, memo)

        return {"v": 1, "t": e.t, "flags": field("flags"), "mode": e.mode,
                "residuals": field("residuals"), "counters": field("counters"),
                "engine_counters": dict(e.counters), "rejected": dict(self.rejected),
                "clock": field("clock"), "temps": dict(self.temps),
                "latency": field("latency"), "fdi": field("fdi"),
                "ud": {"d_min": float(e.d.min()), "d_max": float(e.d.max())}}

    def take_outputs(self) -> list[tuple[str, dict[str, Any]]]:
        out, self._out = self._out, []
        return out


def _now_fields(t: float, q: np.ndarray, omega: np.ndarray) -> dict[str, Any]:
    """Packet fields that a sample-triggered packet takes from the prediction."""
    return {"t": t, "q_body_from_inertial": q.tolist(), "omega_body": omega.tolist()}
