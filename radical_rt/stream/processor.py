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
still held back (:func:`radical_rt.kernels.propagate.predict_attitude`), so its latency is the processing
time of one message, not the tracker latency. This module owns the input and release side; the
output messages and their schedule are in :mod:`radical_rt.stream.outputs`.
"""

from __future__ import annotations

import math
from collections import defaultdict
from typing import Any

import numpy as np

from radical_rt.clock.siru_clock import ClockConfig, SiruClock
from radical_rt.contract.params import ParamTable
from radical_rt.engine.filter import Engine
from radical_rt.engine.gyro_queue import GyroQueue
from radical_rt.stream.block_feed import BlockFeed
from radical_rt.stream.input_guard import TimeJump
from radical_rt.stream.outputs import StreamOutputs
from radical_rt.stream.packets import InputError, decode_siru, decode_temp, decode_tracker, unpack
from radical_rt.stream.siru_wire import (
    SS_WINDOW,
    WIRE_BACKWARDS,
    WIRE_DUPLICATE,
    WIRE_FALLBACK,
    WIRE_JUMP,
    SiruWire,
)
from radical_rt.stream.stream_guard import StreamGuards
from radical_rt.stream.stream_log import StreamLog, bump_applied
from radical_rt.stream.telemetry import PacketSpec, default_packets
from radical_rt.stream.tracker_queue import (
    IN_BACKWARDS,
    IN_DUPLICATE,
    IN_FALLBACK,
    IN_FULL,
    IN_JUMP,
    IN_RELEASE,
    PLAN_GO,
    SI_LATE,
    SS_LAST,
    SS_LAST_SIRU,
    SS_RELEASED,
    SS_T_IN,
    SS_T_MAX,
    TrackerQueue,
    release_plan,
    tracker_accept,
    tracker_intake,
)

INPUT_TOPICS = ("siru", "st1", "st2", "temp")


class StreamProcessor(StreamOutputs, StreamGuards, BlockFeed):
    """Engine + clock + reorder buffer + output scheduling for one vehicle.

    The input sanity rules (time window, jumps, tracker conflicts, losses) and their settings
    are those of :class:`radical_rt.stream.stream_guard.StreamGuards` (docs/node.md, "Time sanity");
    the flags, counters and output messages and their schedule those of
    :class:`radical_rt.stream.outputs.StreamOutputs`."""

    def __init__(self, table: ParamTable | None = None, clock: SiruClock | None = None,
                 packets: dict[str, PacketSpec] | None = None, reorder_slack_s: float = 0.05,
                 diag_period_s: float = 1.0, reject_hold_s: float = 1.0, *,
                 engine_type: type[Engine] = Engine, **guard) -> None:
        """table: the engine's parameter tables; clock: the SIRU clock reconstruction (default
        configuration); packets: telemetry packets (defaults); engine_type: the engine class,
        built here with this processor as its hooks (radical_rt.engine.hooks: the clock's σ of
        the time line, the output wake times, the window hook); the rest: docs/node.md."""
        engine = self.engine = engine_type(table, hooks=self)
        self.clock = clock or SiruClock(ClockConfig(), n_gyro=engine.n_gyro)
        self.packets = packets or default_packets()
        self.reorder_slack_s, self.reject_hold_s = reorder_slack_s, reject_hold_s
        self.diag = PacketSpec("diag", [], period_s=diag_period_s)
        self.rejected: dict[str, int] = defaultdict(int)
        self.tracker_q = TrackerQueue()  # waiting tracker samples and the shared stream times
        self._init_guards(**guard)
        self.temps: dict[str, float] = {}
        self.last_reject_t = -math.inf
        self._out: list[tuple[str, dict[str, Any]]] = []
        self._last_flags = None
        self.gyro_q = GyroQueue(engine.n_gyro)
        self._wire = SiruWire(engine.n_gyro)  # compiled decoding of plain siru messages
        self._pred = np.zeros(9)  # the release kernel's prediction for sample packets (now())
        self.streams = StreamLog()  # stream index (``stream`` of every output) and records
        self._init_block()  # (radical_rt.stream.block_feed: many messages at once)
        self.begin_stream()

    # ---------------------------------------------------------------- input side
    def begin_stream(self) -> None:
        self._guard_begin_stream()
        self.tracker_q.clear()  # t_max, released_t and the trackers' last times: −inf
        self.last_t: dict[str, float] = {}  # temp (siru's and the trackers' are in the queue's ss)
        self.t_now = -math.inf  # newest reconstructed gyro sample time taken in [s]
        self._span_open = True  # the stream's first input time is still to be noted
        self._new_sample = False
        self._block_used = False
        self.gyro_q.clear()

    # newest t_bus of any input [s]; epoch up to which samples count as released [s]; late
    # tracker samples dropped (shared with the compiled intake, radical_rt.stream.tracker_queue)
    t_max = property(lambda self: self.tracker_q.ss.item(SS_T_MAX),
                     lambda self, v: self.tracker_q.ss.__setitem__(SS_T_MAX, v))
    released_t = property(lambda self: self.tracker_q.ss.item(SS_RELEASED),
                          lambda self, v: self.tracker_q.ss.__setitem__(SS_RELEASED, v))
    late_dropped = property(lambda self: self.tracker_q.si.item(SI_LATE),
                            lambda self, v: self.tracker_q.si.__setitem__(SI_LATE, v))

    def feed(self, topic: str, payload: bytes | dict) -> list[tuple[str, dict[str, Any]]]:
        """Take one input message (topic without the leading slash); return outputs produced."""
        released = False
        try:
            if topic not in INPUT_TOPICS:
                raise InputError("unknown_topic", f"unknown input topic {topic!r}")
            if isinstance(payload, (bytes, bytearray, memoryview)) \
                    and len(payload) > self.max_payload_bytes:
                raise InputError("too_large", f"{topic} payload of {len(payload)} bytes exceeds "
                                              f"the bound {self.max_payload_bytes}")
            if topic == "siru":
                self._feed_siru(payload)
            elif topic == "temp":
                t, values = decode_temp(unpack(payload))
                self._check_time(topic, t)
                self.temps.update(values)
            else:
                released = self._feed_tracker(topic, payload)
        except TimeJump as exc:
            self._on_jump(topic, payload, exc)
        except InputError as exc:
            self._reject(topic, exc)
        else:
            if self._jumps.held:  # a message inside the window: the held candidates were false
                self._discard_candidates()
        if self._span_open:
            self._note_first()
        if not released:
            self._release(self.watermark(), defer=topic != "siru")
        if self._new_sample:
            self._new_sample = False
            self._sample_outputs()
        return self.take_outputs()

    def _note_first(self) -> None:
        """The stream's first input taken in: its bus time (the newest t_bus then) opens the
        stream's span."""
        t = self.t_max
        if t > -math.inf:
            self._span_open = False
            self.streams.seen(t)

    def _check_time(self, topic: str, t: float) -> None:
        ss = self.tracker_q.ss
        t_ref, w = float(ss[SS_T_MAX]), float(ss[SS_WINDOW])
        if math.isfinite(t_ref) and (t - t_ref > w or t_ref - t > w):
            raise TimeJump(topic, t, t, t_ref)
        last = self.last_t.get(topic, -math.inf)
        if t == last:
            raise InputError("duplicate", f"{topic} sample at t_bus={t} repeats the previous one")
        if t < last:
            raise InputError("time_backwards", f"{topic} t_bus={t} is before the previous {last}")
        self.last_t[topic] = t
        self.t_max = max(self.t_max, t)

    def _feed_siru(self, payload) -> None:
        """A siru message: decoded, time-checked and pushed through the clock into the gyro
        queue by one kernel call (:meth:`radical_rt.stream.siru_wire.SiruWire.intake`); any other layout
        through msgpack and :func:`radical_rt.stream.packets.decode_siru`, then the same kernel's steps
        (:meth:`radical_rt.stream.siru_wire.SiruWire.accept`)."""
        ss, gq = self.tracker_q.ss, self.gyro_q
        status = WIRE_FALLBACK
        prev = ss.item(SS_LAST_SIRU)
        if isinstance(payload, (bytes, bytearray, memoryview)):
            status, k, m = self._wire.intake(self.clock, payload, gq, ss, SS_LAST_SIRU,
                                             SS_T_MAX)
            t0 = self._wire.t_bus.item(0)
            if status == WIRE_JUMP:
                w = self._wire
                raise TimeJump("siru", t0, float(w.t_bus[k - 1]), float(ss[SS_T_MAX]),
                               (int(w.tt[0]), int(w.tt[k - 1])))
        if status == WIRE_FALLBACK:
            t_bus, tt, dth, st = decode_siru(unpack(payload), self.engine.n_gyro)
            t0 = float(t_bus[0])
            status, m = self._wire.accept(self.clock, t_bus, tt, dth, st, gq, ss, SS_LAST_SIRU,
                                          SS_T_MAX)
            if status == WIRE_JUMP:
                raise TimeJump("siru", t0, float(t_bus[-1]), float(ss[SS_T_MAX]),
                               (int(tt[0]), int(tt[-1])))
        if status == WIRE_DUPLICATE:
            raise InputError("duplicate", f"siru sample at t_bus={t0} repeats the previous one")
        if status == WIRE_BACKWARDS:
            raise InputError("time_backwards",
                             f"siru t_bus={t0} is before the previous {float(ss[SS_LAST_SIRU])}")
        if t0 - prev > self.input_gap_s and prev > -math.inf:  # a gap in the siru bus times
            self._note_input_gap(t0 - prev)
        if m:
            self.t_now = gq.t.item(gq.end - 1)
            self._new_sample = True

    def _feed_tracker(self, topic: str, payload) -> bool:
        """A tracker message: decoded, checked and queued in release order by one kernel call
        (:func:`radical_rt.stream.tracker_queue.tracker_intake`; any other layout through msgpack and
        :func:`radical_rt.stream.packets.decode_tracker`), with the stream's release test. Returns
        whether that test is done (the caller's deferred release then has nothing to do)."""
        j = 1 if topic == "st1" else 2
        e, gq, tq = self.engine, self.gyro_q, self.tracker_q
        si = e.si
        plain = isinstance(payload, (bytes, bytearray, memoryview))
        decoded = None
        if self._conflict.until[j] > -math.inf and self._conflicted(j, topic, payload):
            return False  # in conflict: not used (counted)
        prev = tq.ss.item(SS_LAST + j)
        while True:  # once, or again after the queue grew (IN_FULL: nothing changed)
            code = IN_FALLBACK
            if plain and decoded is None:
                code = tracker_intake(np.frombuffer(payload, np.uint8), j, si.latency_st_s,
                                      self.reorder_slack_s, tq.ss, tq.si, tq.ev_f, tq.ev_i, gq.t,
                                      gq.head, gq.end, e.acc_i.item(0), si.prop_window, tq.q_work)
            if code == IN_FALLBACK:
                decoded = decoded or decode_tracker(unpack(payload))
                code = tracker_accept(*decoded, j, si.latency_st_s, self.reorder_slack_s, tq.ss,
                                      tq.si, tq.ev_f, tq.ev_i, gq.t, gq.head, gq.end,
                                      e.acc_i.item(0), si.prop_window)
            if code != IN_FULL:
                break
            if not tq.grow(self.max_tracker_rows):
                raise InputError("queue_full", f"{topic}: {len(tq)} tracker samples already wait "
                                               f"for release (bound {self.max_tracker_rows})")
        t_in = tq.ss.item(SS_T_IN)
        if code == IN_JUMP:
            raise TimeJump(topic, t_in, t_in, float(tq.ss[SS_T_MAX]))
        q_in = tq.q_work if decoded is None else decoded[1]
        if code >= 0:  # taken in: remembered; closer than one tracker can: evidence (stream_guard)
            self._last_q[j] = q_in.tobytes()
            if abs(t_in - prev) < self._min_interval_s:
                self._conflict_evidence(j, t_in)
        elif abs(t_in - prev) < self._min_interval_s:
            self._tracker_evidence(j, code, t_in, q_in)
        if code == IN_DUPLICATE or code == IN_BACKWARDS:
            t, last = float(tq.ss[SS_T_IN]), float(tq.ss[SS_LAST + j])
            if code == IN_DUPLICATE:
                raise InputError("duplicate",
                                 f"{topic} sample at t_bus={t} repeats the previous one")
            raise InputError("time_backwards", f"{topic} t_bus={t} is before the previous {last}")
        if code == IN_RELEASE:
            self._release(self.watermark(), defer=True)
        return True

    def _reject(self, topic: str, exc: InputError) -> None:
        self.rejected[exc.reason] += 1
        self.last_reject_t = self.t_max
        self.last_reject = f"{topic}: {exc}"

    # ---------------------------------------------------------------- release to the engine
    def watermark(self) -> float:
        """The release watermark t_max − latency − slack [s]: epochs up to it are released."""
        return self.t_max - self.engine.si.latency_st_s - self.reorder_slack_s

    def _release(self, watermark: float, defer: bool = False) -> None:
        """Give the engine every tracker sample with epoch ≤ watermark and the gyro samples up to
        the watermark, in epoch order (one :meth:`Engine.release`).

        defer: when no tracker sample is due and the gyro samples cannot complete a time-update
        window, leave them in the queue for the next release (they count as released for the
        late-tracker test). Nothing observable happens in such a release — no window closes, so
        no output — and the next release processes the same events in the same order; the
        stream defers on tracker and temperature messages, never before sample outputs."""
        gq, e, tq, pred = self.gyro_q, self.engine, self.tracker_q, self._pred
        pred[0] = 0.0  # no prediction from this release (yet)
        a = gq.head
        plan, e1, z = release_plan(tq.ss, tq.si, tq.ev_f, gq.t, a, gq.end, watermark,
                                   e.acc_i.item(0), e.si.prop_window, defer)
        if plan != PLAN_GO:
            return
        gq.head = z  # taken before the engine runs
        predict = None
        if self._sample_packets and not defer:  # the kernel also predicts (see now())
            pred[0], pred[1] = 1.0, self.t_now
            predict = (pred, gq.end) + self.clock.state_arrays()
        e.release(gq.arrays(), a, z, tq.block(e1), predict)

    def end_stream(self, next_start: str | None = "warm",
                   source: str | None = None) -> list[tuple[str, dict[str, Any]]]:
        """Finish the current stream; prepare the next one with a "warm" (bump) or "cold" start.
        source: where the stream's input came from (archive path), kept in its record."""
        self._discard_candidates()  # held jump candidates never confirmed: rejected
        out = self.clock.flush()
        if len(out.t):
            self.gyro_q.push(out)
        if not self._release_final():  # (the block kernel's, when the stream went through it)
            self._release(math.inf)
        if self.engine.att_valid:
            self.engine.flush_parity()
        log = self.streams
        if source is not None:
            log.source = source
        if not self._span_open:
            log.seen(self.t_max)
        if next_start is not None:
            log.end(self.engine)
            self.clock.reset()
            if next_start == "cold":
                self.engine.cold_start()
                log.begin("cold", None)
            else:
                self.engine.warm_start(bump=True)
                log.begin("warm", bump_applied(self.engine.si))
            self.begin_stream()
            for spec in self.packets.values():
                spec.next_t = -math.inf
            self.diag.next_t = -math.inf
            self.packet_wake = None
        return self.take_outputs()

    # ---------------------------------------------------------------- the engine's hooks
    def timing_sigma(self, t: float) -> float:
        """The clock's reconstruction uncertainty [s] (it enters the tracker noise as (ω̂·σ_t)²)."""
        return self.clock.tag_error_sigma_s
