"""Input sanity of one stream beyond the per-message checks: time jumps and tracker takeovers.

Both rules are documented in docs/node.md ("Time sanity"); the stream processor
(:mod:`radical_rt.stream.processor`) applies them, in arrival order, so the batch shell and the node make
the same decisions on the same message sequence.

:class:`JumpGuard` — a message whose t_bus lies outside the plausibility window W around the
stream's newest time (the compiled intakes test it: :func:`radical_rt.stream.siru_wire.outside_window`)
is never adopted. It is held as a jump candidate. Held candidates are consistent when each lies
within W of the span of those held before it and after the held candidates of its own topic (a
new time line goes forward on every topic: replays of old messages and copies of one forged
time do not make one). ``confirm_n`` consecutive consistent candidates among which the last
``confirm_siru`` siru batches continue each other's time tags (the first tag of each one sample,
5000..15000 ticks, after the last tag of the one before) are a genuine jump: ahead of the stream, a
gap (the candidates are then taken in, in order, as if the window had not been there); behind
it, a bus-time reset (the stream ends as between two archives, warm start, and the candidates
open the new stream). Any message taken in normally, or an inconsistent candidate, discards the
held candidates: they are counted as rejected (``time_jump``). At most ``4 · confirm_n``
candidates and ``max_bytes`` of payload are held (the oldest are dropped, counted).

:class:`TrackerConflict` — two samples of one tracker closer than ``min_interval_s`` in t_bus
(one was taken in and the other is refused as going back, or both are taken in) cannot come from
one tracker: evidence of a second source on the topic. ``conflict_n`` pieces of evidence within
``span_s`` of bus time raise a conflict: the tracker's samples are not used (counted
``stj_conflict``) until ``hold_s`` of bus time passes without new evidence. The samples of that
tracker still waiting for release are marked invalid when the conflict is raised.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

TT_WRAP = 1 << 32  # the siru time tag counter wraps (CONTRACT §1.5)
TT_STEP_MIN, TT_STEP_MAX = 5000, 15000  # one sample (10000 ticks of 1 µs) ± 50 %


class TimeJump(ValueError):
    """A message outside the plausibility window (t_first..t_last: its t_bus span [s])."""

    reason = "time_jump"

    def __init__(self, topic: str, t_first: float, t_last: float, t_ref: float,
                 tt: tuple[int, int] | None = None) -> None:
        super().__init__(f"{topic} t_bus={t_first:.6f}..{t_last:.6f} is outside the "
                         f"plausibility window around the stream's newest time {t_ref:.6f}")
        self.topic, self.t_first, self.t_last = topic, t_first, t_last
        self.tt = tt  # a siru batch's first and last time tags


class JumpGuard:
    """Held jump candidates (module docstring)."""

    def __init__(self, window_s: float = 2.0, confirm_n: int = 5, confirm_siru: int = 3,
                 max_bytes: int = 8 << 20) -> None:
        if not (window_s > 0 and confirm_n >= 1 and 0 <= confirm_siru <= confirm_n):
            raise ValueError("time window must be > 0 and 0 ≤ confirm_siru ≤ confirm_n ≥ 1")
        self.window_s, self.confirm_n, self.confirm_siru = window_s, confirm_n, confirm_siru
        self.max_bytes = max_bytes
        self.held: list[tuple[str, Any, float, float, int]] = []
        self._tt_last: int | None = None  # last time tag of the held siru candidates
        self._siru_run = 0  # held siru candidates that continue each other's time tags
        self.gaps = self.resets = 0  # confirmed jumps

    def _span(self) -> tuple[float, float]:
        return min(h[2] for h in self.held), max(h[3] for h in self.held)

    def offer(self, topic: str, payload: Any, exc: TimeJump, t_ref: float
              ) -> tuple[str, list[tuple[str, Any]], list[TimeJump]]:
        """Hold a candidate. Returns (action, messages, discarded): action "held", or "gap" /
        "reset" with the confirmed candidates to take in (in arrival order); discarded: the
        candidates dropped now (to be counted as rejected)."""
        w = self.window_s
        discarded: list[TimeJump] = []
        if self.held:
            lo, hi = self._span()
            prev = max((h[3] for h in self.held if h[0] == topic), default=-math.inf)
            if not (exc.t_first >= lo - w and exc.t_last <= hi + w + (exc.t_last - exc.t_first)
                    and exc.t_first > prev):
                discarded = self.discard()
        nbytes = len(payload) if isinstance(payload, (bytes, bytearray, memoryview)) else 0
        if topic == "siru" and exc.tt is not None:
            step = (exc.tt[0] - self._tt_last) % TT_WRAP if self._tt_last is not None else None
            contiguous = step is not None and TT_STEP_MIN <= step <= TT_STEP_MAX
            self._siru_run = self._siru_run + 1 if contiguous else 1
            self._tt_last = exc.tt[1]
        self.held.append((topic, payload, exc.t_first, exc.t_last, nbytes))
        while len(self.held) > 1 and (len(self.held) > 4 * self.confirm_n
                                      or sum(h[4] for h in self.held) > self.max_bytes):
            discarded.append(self._exc(self.held.pop(0)))
        if len(self.held) < self.confirm_n or self._siru_run < self.confirm_siru:
            return "held", [], discarded
        lo, _hi = self._span()
        action = "gap" if not lo < t_ref else "reset"
        if action == "gap":
            self.gaps += 1
        else:
            self.resets += 1
        msgs = [(h[0], h[1]) for h in self.held]
        self._clear()
        return action, msgs, discarded

    def _clear(self) -> None:
        self.held, self._tt_last, self._siru_run = [], None, 0

    @staticmethod
    def _exc(h: tuple[str, Any, float, float, int]) -> TimeJump:
        return TimeJump(h[0], h[2], h[3], math.nan)

    def discard(self) -> list[TimeJump]:
        """Drop every held candidate; return them (to be counted as rejected)."""
        out = [self._exc(h) for h in self.held]
        self._clear()
        return out


class TrackerConflict:
    """Evidence of a second source on a tracker topic (module docstring)."""

    def __init__(self, min_interval_s: float = 0.005, conflict_n: int = 3, span_s: float = 10.0,
                 hold_s: float = 10.0) -> None:
        self.min_interval_s, self.conflict_n = min_interval_s, conflict_n
        self.span_s, self.hold_s = span_s, hold_s
        self._evidence = {1: deque(), 2: deque()}
        self.until = {1: -math.inf, 2: -math.inf}  # conflict raised until this bus time [s]
        self.last_seen = {1: -math.inf, 2: -math.inf}  # newest t_bus seen while in conflict
        self.dropped = {1: 0, 2: 0}  # samples not used because of a conflict
        self.raised = {1: 0, 2: 0}  # conflicts raised

    def active(self, j: int, t_now: float) -> bool:
        """Whether tracker j is in conflict at bus time t_now [s]."""
        return self.until[j] > -math.inf and t_now <= self.until[j]

    def close(self, j: int, t: float, prev: float) -> bool:
        """Whether t and the tracker's previous t_bus prev are too close for one source."""
        return math.isfinite(prev) and abs(t - prev) < self.min_interval_s

    def note(self, j: int, t: float) -> bool:
        """One piece of evidence at t_bus t [s]; True when this raises a new conflict."""
        ev = self._evidence[j]
        ev.append(t)
        while ev and ev[0] < t - self.span_s:
            ev.popleft()
        was = self.active(j, t)
        if len(ev) >= self.conflict_n or was:
            self.until[j] = max(self.until[j], t + self.hold_s)
            if not was:
                self.raised[j] += 1
                return True
        return False

    def clear(self) -> None:
        """A new stream: no evidence, no conflict (the counters are kept)."""
        for j in (1, 2):
            self._evidence[j].clear()
            self.until[j] = self.last_seen[j] = -math.inf


class HeldFlag:
    """A flag raised by an event and kept until it has been published once in a fault message,
    then for ``hold_s`` of bus time more (so an event set and cleared inside one window is seen)."""

    def __init__(self, hold_s: float = 1.0) -> None:
        self.hold_s = hold_s
        self.pending = False
        self.until = -math.inf

    def set(self) -> None:
        self.pending = True

    def on(self, t: float) -> bool:
        return self.pending or (self.until > -math.inf and t <= self.until)

    def published(self, t: float) -> None:
        """A fault message at bus time t [s] carried the flag."""
        if self.pending:
            self.pending = False
            self.until = t + self.hold_s
