"""Tracker samples waiting for their release, in epoch order, in flat arrays, and the compiled
intake of a tracker message.

The stream processor (:mod:`radical_rt.stream.processor`) holds each tracker sample until the watermark
``t_max − latency − slack`` passes its epoch ``t_bus − latency``. This module keeps the waiting
samples as rows of two arrays in release order (epoch, then tracker 1 before 2, then arrival),
so that a release hands the compiled engine (:func:`radical_rt.engine.loop.run_release`) a row
range instead of building its event arrays sample by sample, and it takes in a whole tracker
message in one kernel call (:func:`tracker_intake`): the msgpack decoding of the plain layout, the
time checks, the late-sample test, the sorted insertion and the stream's test whether a release
is due. Both are what the stream did in Python before, step for step (same comparisons, same
arithmetic), so the event sequence the engine sees is unchanged.

Shared state (owned by the stream processor):

* ``ss`` float64 (7,), the stream's times: ``SS_T_MAX`` (newest t_bus of any input [s]),
  ``SS_RELEASED`` (epoch up to which samples count as released [s]), ``SS_LAST + j`` (last t_bus
  of tracker j = 1, 2), ``SS_T_IN`` (t_bus of the last tracker sample taken in or refused, for
  the diagnostics), ``SS_LAST_SIRU`` (last t_bus of the previous siru batch; the compiled siru
  intake, :func:`radical_rt.stream.siru_wire.siru_intake`, checks and updates it), and
  ``SS_WINDOW`` the plausibility window W [s] of both intakes (configuration, inf: off).
* ``si`` int64 (4,): ``SI_LATE`` (late samples dropped), ``SI_SEQ`` (arrival counter),
  ``SI_HEAD``, ``SI_END`` (the waiting rows are head..end−1).
* rows: ``ev_f`` (cap, 5) epoch [s], q_st_from_inertial (4,); ``ev_i`` (cap, 4) tracker j,
  n_stars, valid, arrival number.
"""

from __future__ import annotations

import numpy as np

from radical_rt._jit import kernel
from radical_rt.stream.packets import MAX_N_STARS, QUAT_NORM_TOL
from radical_rt.stream.siru_wire import be_uint, outside_window, read_int
from radical_rt.stream.stream_layout import (  # noqa: F401 (re-exported for the stream)
    SI,
    SI_END,
    SI_HEAD,
    SI_LATE,
    SI_SEQ,
    SS,
    SS_LAST,
    SS_LAST_SIRU,
    SS_RELEASED,
    SS_T_IN,
    SS_T_MAX,
    SS_WINDOW,
)

# tracker_intake / tracker_accept results
IN_FALLBACK = -1  # not the plain layout: decode it in Python, then tracker_accept
IN_DUPLICATE = -2  # t_bus equals the tracker's previous one (nothing changed)
IN_BACKWARDS = -3  # t_bus before the tracker's previous one (nothing changed)
IN_FULL = -4  # no room for a row (nothing changed): grow, then call again
IN_JUMP = -5  # t_bus outside the stream's plausibility window (nothing changed but ss[SS_T_IN])
IN_IDLE = 0  # taken in (or dropped as late); no release is due
IN_RELEASE = 1  # taken in (or dropped as late); the stream should release now

# release_plan results
PLAN_NOTHING, PLAN_DEFERRED, PLAN_GO = 0, 1, 2



@kernel
def _tracker_key(buf, p, n):
    """A fixstr key at p: (1 v, 2 t_bus, 4 q, 8 n_stars, 16 valid; 0 any other key, −1 not a
    fixstr; next position)."""
    if p >= n or not 0xA0 <= buf[p] <= 0xBF:
        return -1, p
    m, p = buf[p] - 0xA0, p + 1
    if p + m > n:
        return -1, p
    key = 0
    if m == 1 and buf[p] == 0x76:  # "v"
        key = 1
    elif m == 1 and buf[p] == 0x71:  # "q"
        key = 4
    elif m == 5 and buf[p] == 0x74 and buf[p + 1] == 0x5F and buf[p + 2] == 0x62 \
            and buf[p + 3] == 0x75 and buf[p + 4] == 0x73:  # "t_bus"
        key = 2
    elif m == 5 and buf[p] == 0x76 and buf[p + 1] == 0x61 and buf[p + 2] == 0x6C \
            and buf[p + 3] == 0x69 and buf[p + 4] == 0x64:  # "valid"
        key = 16
    elif m == 7 and buf[p] == 0x6E and buf[p + 1] == 0x5F and buf[p + 2] == 0x73 \
            and buf[p + 3] == 0x74 and buf[p + 4] == 0x61 and buf[p + 5] == 0x72 \
            and buf[p + 6] == 0x73:  # "n_stars"
        key = 8
    return key, p + m


@kernel
def _float64(buf, p, n):
    """A msgpack float64 at p: (ok, value, next position); anything else is not ok (the plain
    layout of a tracker message has Python floats, as decode_tracker's short path requires)."""
    if p + 9 <= n and buf[p] == 0xCB:
        return True, np.uint64(be_uint(buf, p + 1, 8)).view(np.float64), p + 9
    return False, 0.0, p


@kernel
def parse_tracker(buf, q_out):
    """Decode the msgpack bytes buf (uint8 (n,)) of a plain tracker message — a map of exactly
    v = 1, t_bus (float), q (4 floats), n_stars (int 0..MAX_N_STARS), valid (bool), any key order, nothing
    after it — with q normalized as :func:`radical_rt.stream.packets.decode_tracker` does (‖q‖ within
    QUAT_NORM_TOL of 1 required). Returns (ok, t_bus, n_stars, valid) and q_out (4,); not ok:
    take the general path (msgpack + decode_tracker), which also names every problem."""
    n = buf.shape[0]
    if n < 1 or buf[0] != 0x85:  # fixmap of 5
        return False, 0.0, 0, False
    p, seen = 1, 0
    t, ns, valid = 0.0, 0, False
    for _ in range(5):
        key, p = _tracker_key(buf, p, n)
        if key <= 0 or seen & key:
            return False, 0.0, 0, False
        seen |= key
        if key == 1:  # v
            ok, v, p = read_int(buf, p, n)
            if not ok or v != 1:
                return False, 0.0, 0, False
        elif key == 2:  # t_bus
            ok, t, p = _float64(buf, p, n)
            if not ok or not np.isfinite(t):
                return False, 0.0, 0, False
        elif key == 4:  # q
            if p >= n or buf[p] != 0x94:
                return False, 0.0, 0, False
            p += 1
            for c in range(4):
                ok, x, p = _float64(buf, p, n)
                if not ok:
                    return False, 0.0, 0, False
                q_out[c] = x
        elif key == 8:  # n_stars
            ok, ns, p = read_int(buf, p, n)
            if not ok or ns < 0 or ns > MAX_N_STARS:
                return False, 0.0, 0, False
        else:  # valid
            if p >= n or (buf[p] != 0xC2 and buf[p] != 0xC3):
                return False, 0.0, 0, False
            valid = buf[p] == 0xC3
            p += 1
    if p != n:
        return False, 0.0, 0, False
    q0, q1, q2, q3 = q_out[0], q_out[1], q_out[2], q_out[3]
    nn = q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3  # decode_tracker's sum, in its order
    if not np.isfinite(nn):
        return False, 0.0, 0, False
    norm = np.sqrt(nn)
    if not abs(norm - 1.0) <= QUAT_NORM_TOL:
        return False, 0.0, 0, False
    for c in range(4):
        q_out[c] = q_out[c] / norm
    return True, t, ns, valid


@kernel
def _upto(t, a, b, wm):
    """Index of the first of the samples t[a:b] (ascending) later than wm (b if none)."""
    if b == a or t[b - 1] <= wm:
        return b
    lo, hi = a, b
    while lo < hi:  # first index with t > wm (searchsorted side="right")
        mid = (lo + hi) // 2
        if t[mid] <= wm:
            lo = mid + 1
        else:
            hi = mid
    return lo


@kernel
def tracker_accept(t, q, n_stars, valid, j, latency, slack, ss, si, ev_f, ev_i, gq_t, gq_head,
                   gq_end, acc0, window):
    """Take in a decoded tracker j sample (t_bus [s], q (4,) normalized, n_stars, valid): the time
    checks against tracker j's previous sample, t_max, the late test against the released epoch
    (late: counted in si[SI_LATE], dropped), the insertion in release order; then the stream's
    release test for the new watermark t_max − latency − slack [s] with the gyro queue's sample
    times gq_t (head..end−1), the engine's current window count acc0 and the window length: a
    release is due if a tracker sample is due or the due gyro samples complete a window; else
    the due gyro samples count as released (ss[SS_RELEASED]). Returns IN_*; on IN_DUPLICATE,
    IN_BACKWARDS, IN_JUMP or IN_FULL nothing has changed (but ss[SS_T_IN])."""
    last = ss[SS_LAST + j]
    ss[SS_T_IN] = t
    if outside_window(ss, SS_T_MAX, t, t, 0.0):
        return IN_JUMP
    if t == last:
        return IN_DUPLICATE
    if t < last:
        return IN_BACKWARDS
    head, end, cap = si[SI_HEAD], si[SI_END], ev_f.shape[0]
    epoch = t - latency
    late = epoch < ss[SS_RELEASED]
    if not late and end >= cap:
        if head == 0:
            return IN_FULL
        for r in range(head, end):  # move the waiting rows to the front
            for c in range(5):
                ev_f[r - head, c] = ev_f[r, c]
            for c in range(4):
                ev_i[r - head, c] = ev_i[r, c]
        end -= head
        head = 0
        si[SI_HEAD], si[SI_END] = head, end
    ss[SS_LAST + j] = t
    ss[SS_T_MAX] = max(ss[SS_T_MAX], t)
    if late:
        si[SI_LATE] += 1
    else:
        si[SI_SEQ] += 1
        pos = end
        while pos > head and (ev_f[pos - 1, 0] > epoch
                              or (ev_f[pos - 1, 0] == epoch and ev_i[pos - 1, 0] > j)):
            for c in range(5):
                ev_f[pos, c] = ev_f[pos - 1, c]
            for c in range(4):
                ev_i[pos, c] = ev_i[pos - 1, c]
            pos -= 1
        ev_f[pos, 0] = epoch
        for c in range(4):
            ev_f[pos, 1 + c] = q[c]
        ev_i[pos, 0], ev_i[pos, 1], ev_i[pos, 2], ev_i[pos, 3] = j, n_stars, valid, si[SI_SEQ]
        si[SI_END] = end + 1
    wm = ss[SS_T_MAX] - latency - slack
    due = si[SI_HEAD] < si[SI_END] and ev_f[si[SI_HEAD], 0] <= wm
    z = _upto(gq_t, gq_head, gq_end, wm)
    if z == gq_head and not due:
        return IN_IDLE
    if not due and acc0 + (z - gq_head) < window:
        ss[SS_RELEASED] = max(ss[SS_RELEASED], gq_t[z - 1])
        return IN_IDLE
    return IN_RELEASE


@kernel
def tracker_intake(buf, j, latency, slack, ss, si, ev_f, ev_i, gq_t, gq_head, gq_end, acc0,
                   window, q_work):
    """:func:`parse_tracker` then :func:`tracker_accept`, in one call: a whole plain tracker
    message. IN_FALLBACK when the message is not in the plain layout (nothing changed)."""
    ok, t, n_stars, valid = parse_tracker(buf, q_work)
    if not ok:
        return IN_FALLBACK
    return tracker_accept(t, q_work, n_stars, valid, j, latency, slack, ss, si, ev_f, ev_i, gq_t,
                          gq_head, gq_end, acc0, window)


@kernel
def release_plan(ss, si, ev_f, gq_t, gq_head, gq_end, wm, acc0, window, defer):
    """The stream's release decision for watermark wm [s]: (PLAN_*, end row of the due tracker
    samples, end index z of the due gyro samples). PLAN_GO: the due tracker rows head..e1−1
    (their largest epoch) and the due gyro samples count as released (ss[SS_RELEASED]); the
    caller then advances the heads. PLAN_DEFERRED (defer and no tracker sample due and the gyro
    samples do not complete a window): only the gyro samples count as released."""
    head, end = si[SI_HEAD], si[SI_END]
    e1 = head
    while e1 < end and ev_f[e1, 0] <= wm:
        e1 += 1
    z = _upto(gq_t, gq_head, gq_end, wm)
    if z == gq_head and e1 == head:
        return PLAN_NOTHING, e1, z
    if defer and e1 == head and acc0 + (z - gq_head) < window:
        ss[SS_RELEASED] = max(ss[SS_RELEASED], gq_t[z - 1])
        return PLAN_DEFERRED, e1, z
    for r in range(head, e1):
        ss[SS_RELEASED] = max(ss[SS_RELEASED], ev_f[r, 0])
    if z > gq_head:
        ss[SS_RELEASED] = max(ss[SS_RELEASED], gq_t[z - 1])
    return PLAN_GO, e1, z


class TrackerQueue:
    """The waiting tracker rows and the shared scalars (module docstring)."""

    def __init__(self, capacity: int = 64) -> None:
        self.ss = np.zeros(SS.end)
        self.ss[SS_WINDOW] = np.inf  # no plausibility window unless the stream sets one
        self.si = np.zeros(SI.end, np.int64)
        self.q_work = np.zeros(4)
        self._alloc(capacity)
        self.clear()

    def _alloc(self, cap: int) -> None:
        self.ev_f, self.ev_i = np.zeros((cap, 5)), np.zeros((cap, 4), np.int64)

    def clear(self) -> None:
        """A new stream: no waiting rows, no times seen (the late counter is kept)."""
        self.ss[:SS_WINDOW] = -np.inf  # (the window is configuration: kept)
        self.si[SI_SEQ:] = 0

    def __len__(self) -> int:
        return int(self.si[SI_END] - self.si[SI_HEAD])

    def grow(self, max_rows: int | None = None) -> bool:
        """Double the capacity (after IN_FULL), keeping the waiting rows; False (nothing
        changed) when more than max_rows rows would wait."""
        h, e = int(self.si[SI_HEAD]), int(self.si[SI_END])
        if max_rows is not None and e - h >= max_rows:
            return False
        old_f, old_i = self.ev_f[h:e].copy(), self.ev_i[h:e].copy()
        self._alloc(2 * self.ev_f.shape[0])
        self.ev_f[:e - h], self.ev_i[:e - h] = old_f, old_i
        self.si[SI_HEAD], self.si[SI_END] = 0, e - h
        return True

    def block(self, e1: int) -> EventBlock:
        """The waiting rows head..e1−1 as an :class:`EventBlock`; the head moves to e1."""
        h = int(self.si[SI_HEAD])
        self.si[SI_HEAD] = e1
        return EventBlock(self, h, e1)


class EventBlock:
    """Rows start..stop−1 of a :class:`TrackerQueue` (absolute row numbers): what one release
    gives the engine. Iterating (or :meth:`event`) gives the Python oracle's tuples
    ``(j, t_epoch, q_meas (4,) copy, n_stars, valid)``."""

    __slots__ = ("tq", "f", "i", "start", "stop")

    def __init__(self, tq: TrackerQueue, start: int, stop: int) -> None:
        self.tq, self.start, self.stop = tq, start, stop
        self.f, self.i = tq.ev_f, tq.ev_i

    def __len__(self) -> int:
        return self.stop - self.start

    def event(self, r: int) -> tuple:
        """Row r as (j, t_epoch, q_meas, n_stars, valid)."""
        j, n_stars, valid, _seq = self.i[r].tolist()
        return j, float(self.f[r, 0]), self.f[r, 1:5].copy(), n_stars, valid != 0

    def __iter__(self):
        return (self.event(r) for r in range(self.start, self.stop))

    def after(self, r: int) -> EventBlock:
        """The rows r..stop−1."""
        return EventBlock(self.tq, r, self.stop)
