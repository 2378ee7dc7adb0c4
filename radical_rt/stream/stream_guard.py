"""The input sanity side of :class:`radical_rt.stream.processor.StreamProcessor` (a mixin).

Rules (docs/node.md, "Time sanity" and "Losses"):

* plausibility window and jumps: :class:`radical_rt.stream.input_guard.JumpGuard`;
* tracker conflicts (a second source on a tracker topic): :class:`~radical_rt.stream.input_guard.
  TrackerConflict`, flags ``ST1_CONFLICT`` / ``ST2_CONFLICT`` (bits 16, 17);
* losses: a siru batch whose first t_bus is more than ``input_gap_s`` after the previous batch's
  last (lost batches, a stopped publisher, a broken link), a confirmed jump, or a loss reported at
  the end of a stream raise ``INPUT_GAP`` (bit 18) and count ``input_gaps`` / ``input_gap_s``;
  ``GYRO_GAP`` (raised by the engine and cleared at the next attitude initialisation, often inside
  one window) is held until a fault message has carried it (:class:`~radical_rt.stream.input_guard.
  HeldFlag`);
* size bounds: a payload longer than ``max_payload_bytes`` is refused before decoding
  (``too_large``); at most ``max_tracker_rows`` tracker samples wait for release (``queue_full``).
"""

from __future__ import annotations

import math
from typing import Any

from radical_rt.contract.flags import Flag
from radical_rt.stream.input_guard import HeldFlag, JumpGuard, TimeJump, TrackerConflict
from radical_rt.stream.packets import decode_tracker, unpack
from radical_rt.stream.siru_wire import SS_WINDOW
from radical_rt.stream.tracker_queue import IN_DUPLICATE, SI_END, SI_HEAD, SS_LAST

_GYRO_GAP, _INPUT_GAP, _LINK_LOSS = int(Flag.GYRO_GAP), int(Flag.INPUT_GAP), int(Flag.LINK_LOSS)
_CONFLICT = {1: int(Flag.ST1_CONFLICT), 2: int(Flag.ST2_CONFLICT)}
MAX_PAYLOAD_BYTES = 1 << 20  # a siru batch of MAX_SIRU_BATCH samples is ≈ 0.6 MB


class StreamGuards:
    """Mixin: needs the stream's ``tracker_q``, ``engine``, ``rejected``, ``_reject``, ``feed``,
    ``end_stream``, ``_out`` and ``t_max``."""

    def _init_guards(self, time_window_s: float = 2.0, jump_confirm_n: int = 5,
                     jump_confirm_siru: int = 3, tracker_min_interval_s: float = 0.005,
                     conflict_n: int = 2, conflict_hold_s: float = 10.0,
                     input_gap_s: float = 0.05, gap_hold_s: float = 1.0,
                     max_payload_bytes: int = MAX_PAYLOAD_BYTES,
                     max_tracker_rows: int = 4096) -> None:
        """time_window_s: the plausibility window W [s]; jump_confirm_n / jump_confirm_siru: the
        consistent candidates (of which siru batches) that confirm a jump; tracker_min_interval_s,
        conflict_n, conflict_hold_s: the tracker conflict rule; input_gap_s: a longer pause in
        the siru bus times is an input gap; gap_hold_s: how long GYRO_GAP / INPUT_GAP stay set
        after a fault message carried them [s of bus time]; max_payload_bytes, max_tracker_rows:
        size bounds."""
        if not (max_payload_bytes >= 1 and max_tracker_rows >= 1 and input_gap_s > 0):
            raise ValueError("max_payload_bytes, max_tracker_rows ≥ 1 and input_gap_s > 0")
        self._jumps = JumpGuard(time_window_s, jump_confirm_n, jump_confirm_siru,
                                max_bytes=4 * jump_confirm_n * max_payload_bytes)
        self._conflict = TrackerConflict(tracker_min_interval_s, conflict_n, span_s=conflict_hold_s,
                                         hold_s=conflict_hold_s)
        self.tracker_q.ss[SS_WINDOW] = time_window_s
        self.input_gap_s, self.max_payload_bytes = input_gap_s, max_payload_bytes
        self.max_tracker_rows = max_tracker_rows
        self._gyro_gap, self._input_gap = HeldFlag(gap_hold_s), HeldFlag(gap_hold_s)
        self._gyro_gaps_seen = 0
        self._last_q = {1: b"", 2: b""}  # bytes of the last quaternion taken in per tracker
        self._min_interval_s = tracker_min_interval_s
        self._guard_live = False  # a held flag or a conflict may be on (else no flag to add)
        self.input_gaps, self.input_gap_total_s, self.reported_lost = 0, 0.0, 0
        self.link_lost, self.link_losses, self.link_lost_s = False, 0, 0.0

    @property
    def time_window_s(self) -> float:
        """The plausibility window W [s] (inf: no time sanity check; set it to change it)."""
        return float(self.tracker_q.ss[SS_WINDOW])

    @time_window_s.setter
    def time_window_s(self, w: float) -> None:
        if not w > 0:
            raise ValueError(f"the time window must be > 0 s, got {w!r}")
        self.tracker_q.ss[SS_WINDOW] = self._jumps.window_s = w

    def _guard_begin_stream(self) -> None:
        self._jumps.held = []
        self._conflict.clear()

    # ------------------------------------------------------------------ jumps
    def _on_jump(self, topic: str, payload: Any, exc: TimeJump) -> None:
        """A message outside the window: held as a candidate; a confirmed jump is taken in."""
        action, msgs, dropped = self._jumps.offer(topic, payload, exc, self.t_max)
        for d in dropped:
            self._reject(d.topic, d)
        if action == "held":
            return
        # (feed and end_stream replace self._out: take their results first, then append)
        if action == "reset":  # a new stream, as between two archives
            self._note_input_gap(0.0)  # (a gap is noted by the siru bus-time test)
            outs = self.end_stream("warm")
            self._out.extend(outs)
            for t, p in msgs:
                outs = self.feed(t, p)
                self._out.extend(outs)
            return
        ss = self.tracker_q.ss
        w, ss[SS_WINDOW] = ss[SS_WINDOW], math.inf  # a gap: as if there were no window
        try:
            for t, p in msgs:
                outs = self.feed(t, p)
                self._out.extend(outs)
        finally:
            ss[SS_WINDOW] = w

    def _discard_candidates(self) -> None:
        for d in self._jumps.discard():
            self._reject(d.topic, d)

    # ------------------------------------------------------------------ tracker conflicts
    def _tracker_evidence(self, j: int, code: int, t: float, q) -> None:
        """A tracker sample refused (code: IN_*) closer than the minimum interval to the
        tracker's previous one (t: its t_bus [s], q: its quaternion): evidence of a second source,
        unless it exactly repeats the previous one (same t_bus and quaternion: a re-sent message,
        refused as a duplicate). (A sample taken in is handled inline by the stream.)"""
        if code == IN_DUPLICATE and q.tobytes() == self._last_q[j]:
            return
        self._conflict_evidence(j, t)

    def _conflict_evidence(self, j: int, t: float) -> None:
        self._guard_live = True
        c = self._conflict
        c.last_seen[j] = max(c.last_seen[j], t)
        if c.note(j, t):  # raised now: the samples of tracker j still waiting are not used
            tq = self.tracker_q
            h, e = int(tq.si[SI_HEAD]), int(tq.si[SI_END])
            for r in range(h, e):
                if tq.ev_i[r, 0] == j and tq.ev_i[r, 2]:
                    tq.ev_i[r, 2] = 0
                    c.dropped[j] += 1

    def _conflicted(self, j: int, topic: str, payload: Any) -> bool:
        """While tracker j is (or was) in conflict: watch its samples; True: not used."""
        c = self._conflict
        t = decode_tracker(unpack(payload))[0]
        if not c.active(j, max(t, c.last_seen[j])) and t > c.last_seen[j]:
            c.until[j] = -math.inf  # the conflict is over: back to the normal intake
            self.tracker_q.ss[SS_LAST + j] = max(float(self.tracker_q.ss[SS_LAST + j]), c.last_seen[j])
            return False
        if c.close(j, t, c.last_seen[j]) or t <= c.last_seen[j]:
            c.note(j, t)
        c.last_seen[j] = max(c.last_seen[j], t)
        c.dropped[j] += 1
        return True

    # ------------------------------------------------------------------ losses and flags
    def _note_input_gap(self, dt: float) -> None:
        self.input_gaps += 1
        self.input_gap_total_s += dt
        self._input_gap.set()
        self._guard_live = True

    def note_takeover_loss(self, dt: float) -> None:
        """A fleet worker resumed this vehicle from a checkpoint ``dt`` s of wall time old (the
        input since then went with the crashed owner): an input gap (INPUT_GAP, counted)."""
        self._note_input_gap(max(0.0, float(dt)))

    def note_reported_loss(self, n: int) -> None:
        """Messages a publisher reported sent that never arrived (end-of-stream marker)."""
        if n > 0:
            self.reported_lost += n
            self._input_gap.set()
            self._guard_live = True

    def note_link_loss(self, lost: bool, length_s: float = 0.0) -> None:
        """The node found the link lost (no input for its stale time: LINK_LOSS set, counted)
        or restored after ``length_s`` of wall time (cleared; radical_rt.apps.link_watch)."""
        if lost and not self.link_lost:
            self.link_losses += 1
        elif not lost and self.link_lost:
            self.link_lost_s += max(0.0, float(length_s))
        self.link_lost = bool(lost)

    def fault_now(self) -> list[tuple[str, dict[str, Any]]]:
        """The fault message due now if the flags changed since the last one (e.g. a loss noted
        at the end of a stream, when no window closes any more)."""
        if self.flags != self._last_flags:
            self._emit_fault(self.engine.t)
        return self.take_outputs()

    def _guard_flags(self) -> int:
        e, f = self.engine, (_LINK_LOSS if self.link_lost else 0)
        g = e.gyro_gaps()
        if g != self._gyro_gaps_seen:
            self._gyro_gaps_seen = g
            self._gyro_gap.set()
            self._guard_live = True
        if not self._guard_live:  # the common case: nothing held, no conflict
            return f
        t = e.t
        if self._gyro_gap.on(t):
            f |= _GYRO_GAP
        if self._input_gap.on(t):
            f |= _INPUT_GAP
        c = self._conflict
        for j in (1, 2):
            if c.until[j] > -math.inf and c.active(j, max(self.t_max, c.last_seen[j])):
                f |= _CONFLICT[j]
        if not f and not any(h.pending or h.until >= t for h in (self._gyro_gap, self._input_gap)) \
                and c.until[1] == -math.inf and c.until[2] == -math.inf:
            self._guard_live = False
        return f

    def _guard_published(self, flags: int, t: float) -> None:
        if flags & _GYRO_GAP:
            self._gyro_gap.published(t)
        if flags & _INPUT_GAP:
            self._input_gap.published(t)

    def _guard_wake(self) -> float:
        """Engine time at which a held flag ends (inf: none)."""
        w, last = math.inf, self._last_flags or 0
        for h, bit in ((self._gyro_gap, _GYRO_GAP), (self._input_gap, _INPUT_GAP)):
            if last & bit and h.until > -math.inf:
                w = min(w, h.until + 1e-6)
        return w

    def _guard_counters(self) -> dict[str, Any]:
        c = self._conflict
        return {"input_gaps": self.input_gaps, "input_gap_s": self.input_gap_total_s,
                "time_jumps_confirmed": self._jumps.gaps + self._jumps.resets,
                "input_reported_lost": self.reported_lost,
                "link_losses": self.link_losses, "link_lost_s": self.link_lost_s,
                "st1_conflict": c.dropped[1], "st2_conflict": c.dropped[2]}
