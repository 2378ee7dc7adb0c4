"""Many input messages at once: :meth:`BlockFeed.feed_many`, the stream processor's batch entry
(``radical process`` reads an archive this way).

The result is the one of :meth:`radical_rt.stream.processor.StreamProcessor.feed` called on
each message in turn, bit for bit (tests/radical_rt/stream/test_block_feed.py): the messages go
through the compiled block intake (:func:`radical_rt.stream.intake_block.intake_block`), which
runs the same intake kernels, release decisions and compiled release, and stops wherever Python
has work; Python then does exactly what ``feed`` does there (the window hook and the rest of a
release, the sample-triggered packets, a gap, conflict evidence) or feeds the message itself (any
message outside the common case). The block is used only while the stream is in its common
state (no held jumps, live guards or unconfirmed gyro gaps, no FDI bank running in the hook, the
product's engine and clock); otherwise the messages go through ``feed``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from radical_rt.clock.siru_clock import SiruClock
from radical_rt.contract.flags import Flag
from radical_rt.engine.engine_state import MODE_NAME
from radical_rt.engine.filter import Engine
from radical_rt.stream import stream_layout as SL
from radical_rt.stream.intake_block import (
    B_BAIL,
    B_END,
    B_RESUME,
    B_SIRU,
    B_SIRU_GAP,
    B_TRK_TAIL,
    T_OTHER,
    T_SIRU,
    T_ST1,
    T_ST2,
    T_TEMP,
    intake_block,
)
from radical_rt.stream.telemetry import SMALL, build
from radical_rt.stream.temp_wire import TEMP_COLS, TEMP_NAMES
from radical_rt.stream.tracker_queue import IN_RELEASE

_CODE = {"siru": T_SIRU, "st1": T_ST1, "st2": T_ST2, "temp": T_TEMP}
_TEMP_ROWS = 64  # temp messages one block call may take
_NO_BYTES, _NO_INTS = np.frombuffer(b"", np.uint8), np.zeros(0, np.int64)  # (no messages)
_LINK_LOSS = int(Flag.LINK_LOSS)


class BlockFeed:
    """Mixin of :class:`radical_rt.stream.processor.StreamProcessor`: :meth:`feed_many`."""

    def _init_block(self) -> None:
        """The block intake's control arrays (BI, BF of radical_rt.stream.stream_layout) and the
        quaternion of the last tracker sample it took in per tracker (3, 4), the rows of the temp
        messages it took in (radical_rt.stream.temp_wire)."""
        self._bi, self._bf = np.zeros(SL.BI.end, np.int64), np.zeros(SL.BF.end)
        self._block_q = np.zeros((3, 4))
        self._temp_f = np.zeros((_TEMP_ROWS, TEMP_COLS))

    def feed_many(self, messages: list[tuple[str, bytes]]) -> list[tuple[str, dict[str, Any]]]:
        """Take input messages (topic without the leading slash, payload bytes) in order;
        return the outputs they produced, as :meth:`feed` on each would."""
        n = len(messages)
        if n == 0:
            return []
        if not all(isinstance(p, bytes) for _t, p in messages):
            out: list = []
            for topic, payload in messages:
                out += self.feed(topic, payload)
            return out
        names = sorted({t for t, _p in messages})
        index = {t: k for k, t in enumerate(names)}
        tidx = np.fromiter((index[t] for t, _p in messages), np.int64, n)
        size = np.fromiter((len(p) for _t, p in messages), np.int64, n)
        off = np.zeros(n, np.int64)
        np.cumsum(size[:-1], out=off[1:])
        buf = np.frombuffer(b"".join(p for _t, p in messages), np.uint8)
        return self.feed_arrays(buf, names, tidx, off, size)

    def feed_arrays(self, buf: np.ndarray, names: list[str], tidx: np.ndarray, off: np.ndarray,
                    size: np.ndarray) -> list[tuple[str, dict[str, Any]]]:
        """:meth:`feed_many` of messages given as arrays: message i is topic names[tidx[i]]
        (without the leading slash) with payload buf[off[i]:off[i] + size[i]] (buf uint8, e.g.
        a decompressed MCAP chunk, radical_rt.io.archive.ArchiveReader.iter_blocks)."""
        n = len(tidx)
        topics = np.array([_CODE.get(t, T_OTHER) for t in names], np.int64)[tidx]
        out: list = []
        i = 0
        while i < n:
            if not self._block_ready() or not self._block_call(buf, topics, off, size, n, i):
                out += self.take_outputs()
                out += self.feed(names[tidx[i]], buf[off[i]:off[i] + size[i]].tobytes())
                i += 1
                continue
            status, i = self._block_status(buf, topics, off, size, n)
            if status == B_END:
                break
            if status == B_BAIL:
                out += self.take_outputs()
                out += self.feed(names[tidx[i]], buf[off[i]:off[i] + size[i]].tobytes())
            else:
                self._block_tail(status, int(topics[i]))
            i += 1
        return out + self.take_outputs()

    def _block_status(self, buf, topics, off, size, n: int) -> tuple[int, int]:
        """(status, message) of the last block call, after the window hooks it stopped for
        (B_RESUME): each hook, then the rest of that release by the kernel again (the calls
        that follow may stop for the next hook), or by the engine's shell when the block cannot
        take it (an FDI bank started, a guard went live; the status is then B_RESUME: the
        message's own tail is left)."""
        bi = self._bi
        while int(bi[SL.BI_STATUS]) == B_RESUME:
            v = bi.tolist()
            bi[SL.BI_RE] = self.engine.hook_after(v[SL.BI_RREASON], v[SL.BI_RSTAGE],
                                                  v[SL.BI_RE], self.tracker_q.ev_f)
            if not (self._block_ready()
                    and self._block_call(buf, topics, off, size, n, v[SL.BI_NEXT], True)):
                self._continue_release()
                return B_RESUME, v[SL.BI_NEXT]
        return int(bi[SL.BI_STATUS]), int(bi[SL.BI_NEXT])

    def _continue_release(self) -> None:
        """The rest of the release the block left at BI_R* (after its window hook), by the
        engine's shell (the block cannot take it: an FDI bank started, a guard went live)."""
        v = self._bi.tolist()
        predict = None
        if v[SL.BI_RPRED]:
            predict = (self._pred, self.gyro_q.end) + self.clock.state_arrays()
        self.engine.continue_release(self.gyro_q.arrays(), v[SL.BI_RK], v[SL.BI_RZ],
                                     self.tracker_q.ev_f, self.tracker_q.ev_i, v[SL.BI_RE],
                                     v[SL.BI_RN], predict)

    # ---------------------------------------------------------------- one call
    def _block_ready(self) -> bool:
        """Whether the next messages may go through the block: the stream in its common state
        (module docstring)."""
        e = self.engine
        return (type(e) is Engine and type(self.clock) is SiruClock and not self._span_open
                and not self._jumps.held and not self._guard_live
                and e.gyro_gaps() == self._gyro_gaps_seen)

    def _release_final(self) -> bool:
        """End of a stream that went through the block: its release of everything (watermark
        inf, StreamProcessor.end_stream) by the block kernel too, with the window hooks it stops
        for. False (nothing done): the caller releases (the shell's path: the block was not used
        in this stream — the node — or cannot run now)."""
        if not (self._block_used and self._block_ready()):
            return False
        none = (_NO_BYTES, _NO_INTS, _NO_INTS, _NO_INTS, 0)
        if not self._block_call(*none, 0, final=True):
            return False
        self._block_status(*none)
        return True

    _block_used = False  # the block took messages of this stream (begin_stream clears it)

    def _block_call(self, buf, topics, off, size, n: int, i: int, resume: bool = False,
                    final: bool = False) -> bool:
        """Room made, the controls set, one :func:`intake_block` call from message i (resume:
        first the rest of its release, BI_R*; final: the release of everything, no message),
        the state read back. False (nothing done): the engine's shell must make the calls (FDI
        bank)."""
        gq, tq, e, clock = self.gyro_q, self.tracker_q, self.engine, self.clock
        cap = self._wire.capacity
        sp_f, sp_i, rows_f, rows_i, k_siru = self._block_rows()
        new = k_siru * cap * (int(clock.config.max_bridge) + 1)  # samples k_siru messages can add
        rows = len(tq) + 3 * k_siru
        if resume:  # (a release in flight holds rows of the queue: nothing may move them; the
            I, F, chunk, OF, OI, tags = clock.prepare(0, gq)  # kernel checks the room it needs)
            rows += int(self._bi[SL.BI_RN] - self._bi[SL.BI_RE])
        else:
            I, F, chunk, OF, OI, tags = clock.prepare(cap, gq)
            gq.reserve(new)
        calls = e.outside_calls(len(gq) + new, rows)
        if calls is None:
            return False
        (wake_fdi, fq, R1, R2, fb, ib, bb, lay, cfg, io, cnt, bfb, bib, bbb, blay, g_f, g_i, g_b,
         g_end, trk_f, trk_i, trk_end, trk_seq) = calls
        bi, bf = self._block_controls(chunk, wake_fdi)
        bi[SL.BI_NEXT], bi[SL.BI_GQ_HEAD], bi[SL.BI_GQ_END] = i, gq.head, gq.end
        bi[SL.BI_G_END], bi[SL.BI_TRK_END], bi[SL.BI_TRK_SEQ] = g_end, trk_end, trk_seq
        bi[SL.BI_SIRU_LEFT], bi[SL.BI_ROWS_OK] = k_siru, k_siru > 1
        bi[SL.BI_RESUME], bi[SL.BI_FINAL] = resume, final
        self._block_used = True
        w = self._wire
        intake_block(buf, topics, off, size, n, bi, bf, w.t_bus, w.tt, w.dtheta, w.status,
                     tq.ss, tq.si, tq.ev_f, tq.ev_i, tq.q_work, self._block_q, I, F, OF, OI,
                     tags, gq.t, gq.dt, gq.dtheta, gq.status, gq.bridged, gq.var_extra,
                     e.acc_i, R1, R2, fb, ib, bb, lay, cfg, io, cnt, g_f, g_i, g_b, self._pred,
                     bfb, bib, bbb, blay, trk_f, trk_i, sp_f, sp_i, rows_f, rows_i, fq, self._temp_f)
        v = bi.tolist()
        if v[SL.BI_TEMPS]:
            self._temps_done(v[SL.BI_TEMPS])
        if k_siru > 1:
            self._rows_done(v[SL.BI_ROWS])
        gq.head, gq.end = v[SL.BI_GQ_HEAD], v[SL.BI_GQ_END]
        e.outside_done(v[SL.BI_G_END], v[SL.BI_TRK_END], v[SL.BI_TRK_SEQ], v[SL.BI_RELEASED] != 0)
        if v[SL.BI_SIRU_M] >= 0:
            clock.took(v[SL.BI_SIRU_M])
        self.t_now = float(bf[SL.BF_T_NOW])
        for j in (1, 2):
            if v[SL.BI_TOOK + j]:
                self._last_q[j] = self._block_q[j].tobytes()
        return True

    def _block_controls(self, chunk: int, wake_fdi: float) -> tuple[np.ndarray, np.ndarray]:
        """The block's control arrays with the stream's current settings and wake inputs (the
        rule of StreamOutputs.wake; its flags part is the kernel's). The settings (no kernel
        writes them) are written when they differ from those of the last call."""
        bi, bf = self._bi, self._bf
        e = self.engine
        last, until = self._last_flags, self._conflict.until
        settings = (-1 if last is None else last, _LINK_LOSS if self.link_lost else 0,
                    1 if self._sample_packets else 0, until[1] > -math.inf, until[2] > -math.inf,
                    self.max_payload_bytes, e.si.prop_window, e.n_gyro, chunk,
                    int(self.clock.config.max_bridge), self.input_gap_s, self._min_interval_s,
                    e.si.latency_st_s, self.reorder_slack_s, self.last_reject_t,
                    self.reject_hold_s)
        if settings != self._settings:
            self._settings = settings
            (bi[SL.BI_LAST_FLAGS], bi[SL.BI_GUARD_FLAGS], bi[SL.BI_SAMPLE_PACKETS],
             bi[SL.BI_CONFLICT + 1], bi[SL.BI_CONFLICT + 2], bi[SL.BI_MAX_PAYLOAD],
             bi[SL.BI_WINDOW], bi[SL.BI_N_GYRO], bi[SL.BI_CHUNK], bi[SL.BI_MAX_BRIDGE],
             bf[SL.BF_INPUT_GAP], bf[SL.BF_MIN_INTERVAL], bf[SL.BF_LATENCY], bf[SL.BF_SLACK],
             bf[SL.BF_LAST_REJECT], bf[SL.BF_REJECT_HOLD]) = settings
        wake_t = self.packet_wake
        if wake_t is None:
            wake_t = self.packet_wake = self._next_packet_t()
        bf[SL.BF_WAKE_T], bf[SL.BF_WAKE_E], bf[SL.BF_WAKE_FDI] = wake_t, self._guard_wake(), wake_fdi
        bf[SL.BF_T_NOW] = self.t_now
        bf[SL.BF_LAST_TEMP] = self.last_t.get("temp", -math.inf)
        return bi, bf

    _settings: tuple | None = None  # the settings _block_controls last wrote

    def _temps_done(self, n: int) -> None:
        """The kernel's rows of the n temp messages it took in, in order: the temperatures and
        the last temp time, as :meth:`feed` keeps them."""
        temps = self.temps
        for row in self._temp_f[:n].tolist():
            for name, value in zip(TEMP_NAMES, row[1:], strict=True):
                if value == value:  # (NaN: not in the message)
                    temps[name] = value
        self.last_t["temp"] = float(self._bf[SL.BF_LAST_TEMP])

    # ---------------------------------------------------------------- sample-triggered packets
    #: the fields a sample-triggered packet may have for the block to make it from a row
    ROW_FIELDS = frozenset(("seq", "t", "q_body_from_inertial", "omega_body", "flags", "mode"))
    #: siru messages one block call may take when their sample packets are made as rows
    K_SIRU = 32
    _rows_cache: tuple | None = None  # (the specs it was made for, sp_f, sp_i, rows_f, rows_i, k,
    #   per spec whether its fields are the default small packet's)

    def _block_rows(self) -> tuple:
        """(sp_f, sp_i, rows_f, rows_i, k_siru) for the sample-triggered packets (the kernel's
        schedule arrays loaded from the packets' specs); k_siru = 1 (one siru message a call,
        the packets Python's) when a packet has a field the rows do not carry."""
        specs = self._sample_specs
        cache = self._rows_cache
        if cache is None or cache[0] is not specs:
            ok = all(set(spec.fields) <= self.ROW_FIELDS for _key, spec in specs)
            k, n = (self.K_SIRU if ok else 1), len(specs)
            cache = self._rows_cache = (specs, np.zeros((n, 2)), np.zeros((n, 2), np.int64),
                                        np.zeros((k * n, 8)), np.zeros((k * n, 3), np.int64), k,
                                        [spec.fields == SMALL for _key, spec in specs])
        sp_f, sp_i = cache[1], cache[2]
        for s, (_key, spec) in enumerate(specs):
            sp_f[s, 0], sp_f[s, 1] = spec.next_t, float(spec.period_s or 0.0)
            sp_i[s, 0], sp_i[s, 1] = spec.decimation or 0, spec.windows
        return cache[1:6]

    def _rows_done(self, n: int) -> None:
        """The kernel's rows of sample-triggered packets (n) as messages, in order; the packets'
        schedule back into their specs."""
        _specs, sp_f, sp_i, rows_f, rows_i, _k, small = self._rows_cache
        specs, out, stream = self._sample_specs, self._out, self.streams.index
        if n:
            for (s, flags, mode), row in zip(rows_i[:n].tolist(), rows_f[:n].tolist(), strict=True):
                key, spec = specs[s]
                if small[s]:  # the contract's small packet: the map build() makes, written out
                    spec.seq += 1
                    out.append((key, {"v": 1, "stream": stream, "seq": spec.seq, "t": row[0],
                                      "q_body_from_inertial": row[1:5], "flags": flags,
                                      "mode": MODE_NAME[mode]}))
                    continue
                now = {"t": row[0], "q_body_from_inertial": row[1:5], "omega_body": row[5:8],
                       "flags": flags, "mode": MODE_NAME[mode]}
                out.append((key, build(spec, self, now)))
        for s, (_key, spec) in enumerate(specs):
            spec.next_t, spec.windows = float(sp_f[s, 0]), int(sp_i[s, 1])

    # ---------------------------------------------------------------- after a call
    def _block_tail(self, status: int, code: int) -> None:
        """The rest of message BI_NEXT after the block stopped there with ``status`` (not
        B_END, B_BAIL; B_RESUME: after the rest of its release; code: the message's T_*), as
        :meth:`feed` would do it."""
        bi, bf = self._bi, self._bf
        if status == B_SIRU_GAP:
            self._note_input_gap(float(bf[SL.BF_T_IN]) - float(bf[SL.BF_PREV]))
            self._release(self.watermark())
        elif status == B_TRK_TAIL:
            self._conflict_evidence(code, float(bf[SL.BF_T_IN]))
            if int(bi[SL.BI_CODE]) == IN_RELEASE:
                self._release(self.watermark(), defer=True)
        if code == T_SIRU and bi[SL.BI_NEW_SAMPLE] and not (status == B_SIRU and bi[SL.BI_ROWS_OK]):
            self._sample_outputs()  # (unless the kernel made them as rows)
