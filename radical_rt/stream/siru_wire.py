"""A compiled fast path for the most frequent input message: a well-formed ``siru`` batch.

:func:`parse_siru` reads the msgpack bytes of a ``siru`` message (CONTRACT §3) straight into
preallocated column buffers, in one kernel call, without building the Python map and its lists
(``msgpack.unpackb`` + :func:`radical_rt.stream.packets.decode_siru` cost ≈ 8 µs per 10-sample batch,
≈ 7 % of the whole batch run). It accepts only the plain layout the contract describes:

* a map (fixmap/map16/map32) whose keys are exactly ``v``, ``t_bus``, ``tt``, ``dtheta``,
  ``status``, each once, in any order, as str keys;
* ``v`` the integer 1;
* ``t_bus`` and ``dtheta`` (rows of ``n_gyro``) numbers: float64, float32 or integers (converted
  to float64 as numpy does); ``tt`` and ``status`` integers within int64;
* columns of one length k in 1..:data:`radical_rt.stream.packets.MAX_SIRU_BATCH`, that also pass the
  column checks of ``decode_siru`` (finite values, tt in [0, 2³²), status ≥ 0, t_bus not
  decreasing, |dtheta| ≤ MAX_DTHETA_RAD); no bytes after the map.

Anything else — another key, a bool, nil, a duplicate key, a truncated or malformed buffer, a value
that decode_siru would reject — returns :data:`FALLBACK`, and the caller takes the general path
(``msgpack`` and ``decode_siru``), which accepts the same messages with the same values and names
the problem of every other one. So the fast path never rejects a message and never decides what
a message means; ``tests/radical_rt/stream/test_siru_wire.py`` checks it against the general path on seeded random
messages and on corrupted ones.
"""

from __future__ import annotations

import numpy as np

from radical_rt._jit import kernel
from radical_rt.clock.clock_kernels import clock_push_rows
from radical_rt.contract.conventions import SIRU_TT_WRAP
from radical_rt.stream.packets import MAX_DTHETA_RAD, MAX_SIRU_BATCH
from radical_rt.stream.stream_layout import SS_WINDOW

FALLBACK = -1  # not the plain layout (or not valid): take the general path
# siru_intake statuses
WIRE_OK, WIRE_FALLBACK, WIRE_GROW, WIRE_DUPLICATE, WIRE_BACKWARDS = 0, 1, 2, 3, 4
WIRE_JUMP = 5  # outside the stream's plausibility window (docs/node.md, "Time sanity")
# the stream's plausibility window W [s] in the shared stream times (ss[SS_WINDOW]; inf: off):
# a message whose newest t_bus is more than W + k·SPAN_PER_SAMPLE_S after the newest t_bus of
# the stream, or whose oldest is more than W before it, is a jump candidate, not taken in
SPAN_PER_SAMPLE_S = 0.02  # allowance per sample of a siru batch (two nominal 10-ms periods)
# k_needed < 0 below FALLBACK: −(2 + k) asks for column buffers of k rows



@kernel
def be_uint(buf, p, nbytes):
    """Big-endian unsigned integer of nbytes at buf[p] (uint8 array) as int64 bits (uint64)."""
    v = np.uint64(0)
    for i in range(nbytes):
        v = (v << np.uint64(8)) | np.uint64(buf[p + i])
    return v


@kernel
def _array_len(buf, p, n):
    """Array header at p: (length, position after the header); length −1 if not an array."""
    if p >= n:
        return -1, p
    b = buf[p]
    if 0x90 <= b <= 0x9F:
        return b - 0x90, p + 1
    if b == 0xDC and p + 3 <= n:
        return np.int64(be_uint(buf, p + 1, 2)), p + 3
    if b == 0xDD and p + 5 <= n:
        return np.int64(be_uint(buf, p + 1, 4)), p + 5
    return -1, p


@kernel
def _number(buf, p, n):
    """A number at p as float64: (ok, value, next position). float64/float32/int of msgpack."""
    if p >= n:
        return False, 0.0, p
    b = buf[p]
    if b == 0xCB and p + 9 <= n:
        return True, np.uint64(be_uint(buf, p + 1, 8)).view(np.float64), p + 9
    if b == 0xCA and p + 5 <= n:
        return True, np.float64(np.uint32(be_uint(buf, p + 1, 4)).view(np.float32)), p + 5
    ok, iv, q = read_int(buf, p, n)
    return ok, np.float64(iv), q


@kernel
def read_int(buf, p, n):
    """An integer at p that fits int64: (ok, value, next position)."""
    if p >= n:
        return False, 0, p
    b = buf[p]
    if b <= 0x7F:
        return True, np.int64(b), p + 1
    if b >= 0xE0:
        return True, np.int64(b) - 256, p + 1
    if 0xCC <= b <= 0xCF:  # uint8..uint64
        w = 1 << (b - 0xCC)
        if p + 1 + w > n:
            return False, 0, p
        v = be_uint(buf, p + 1, w)
        if v > np.uint64(9223372036854775807):
            return False, 0, p
        return True, np.int64(v), p + 1 + w
    if 0xD0 <= b <= 0xD3:  # int8..int64, two's complement
        w = 1 << (b - 0xD0)
        if p + 1 + w > n:
            return False, 0, p
        v = np.int64(be_uint(buf, p + 1, w))
        if w < 8 and v >= (np.int64(1) << (8 * w - 1)):
            v -= np.int64(1) << (8 * w)
        return True, v, p + 1 + w
    return False, 0, p


@kernel
def _key(buf, p, n):
    """A str key at p: (1 v, 2 t_bus, 4 tt, 8 dtheta, 16 status; 0 any other key, −1 not a str;
    next position)."""
    if p >= n:
        return -1, p
    b = buf[p]
    if 0xA0 <= b <= 0xBF:
        m, p = b - 0xA0, p + 1
    elif b == 0xD9 and p + 2 <= n:
        m, p = buf[p + 1], p + 2
    else:
        return -1, p
    if p + m > n:
        return -1, p
    if m == 1 and buf[p] == 0x76:  # "v"
        return 1, p + m
    if m == 2 and buf[p] == 0x74 and buf[p + 1] == 0x74:  # "tt"
        return 4, p + m
    if m == 5 and buf[p] == 0x74 and buf[p + 1] == 0x5F and buf[p + 2] == 0x62 \
            and buf[p + 3] == 0x75 and buf[p + 4] == 0x73:  # "t_bus"
        return 2, p + m
    if m == 6 and buf[p] == 0x64 and buf[p + 1] == 0x74 and buf[p + 2] == 0x68 \
            and buf[p + 3] == 0x65 and buf[p + 4] == 0x74 and buf[p + 5] == 0x61:  # "dtheta"
        return 8, p + m
    if m == 6 and buf[p] == 0x73 and buf[p + 1] == 0x74 and buf[p + 2] == 0x61 \
            and buf[p + 3] == 0x74 and buf[p + 4] == 0x75 and buf[p + 5] == 0x73:  # "status"
        return 16, p + m
    return 0, p + m


@kernel
def parse_siru(buf, n_gyro, t_bus, tt, dtheta, status, max_k, tt_wrap):
    """Decode the msgpack bytes buf (uint8 (n,)) of a plain ``siru`` message (module docstring)
    into t_bus (cap,) [s], tt (cap,) int64, dtheta (cap, n_gyro) [rad], status (cap,) int64.
    Returns k (the batch length, ≥ 1) on success; :data:`FALLBACK` (−1) when the message is not
    in the plain layout or would be rejected; −(2 + k) when the buffers hold fewer than k rows
    (grow them and call again). Never raises."""
    n = buf.shape[0]
    if n == 0:
        return -1
    b = buf[0]
    if 0x80 <= b <= 0x8F:
        n_keys, p = b - 0x80, 1
    elif b == 0xDE and n >= 3:
        n_keys, p = np.int64(be_uint(buf, 1, 2)), 3
    elif b == 0xDF and n >= 5:
        n_keys, p = np.int64(be_uint(buf, 1, 4)), 5
    else:
        return -1
    if n_keys != 5:
        return -1
    seen, k, cap = 0, -1, t_bus.shape[0]
    for _ in range(5):
        key, p = _key(buf, p, n)
        if key <= 0 or seen & key:
            return -1
        seen |= key
        if key == 1:  # v
            ok, v, p = read_int(buf, p, n)
            if not ok or v != 1:
                return -1
            continue
        m, p = _array_len(buf, p, n)
        if m < 1 or m > max_k or (k >= 0 and m != k):
            return -1
        k = m
        if k > cap:
            return -(2 + k)
        for i in range(k):
            if key == 2:
                ok, x, p = _number(buf, p, n)
                t_bus[i] = x
            elif key == 8:
                row, p = _array_len(buf, p, n)
                if row != n_gyro:
                    return -1
                for j in range(n_gyro):
                    ok, x, p = _number(buf, p, n)
                    if not ok:
                        return -1
                    dtheta[i, j] = x
            else:
                ok, iv, p = read_int(buf, p, n)
                if key == 4:
                    tt[i] = iv
                else:
                    status[i] = iv
            if not ok:
                return -1
    if p != n:
        return -1
    for i in range(k):  # decode_siru's column checks: a failure is the general path's to name
        if not np.isfinite(t_bus[i]) or tt[i] < 0 or tt[i] >= tt_wrap or status[i] < 0:
            return -1
        if i > 0 and t_bus[i] < t_bus[i - 1]:
            return -1
        for j in range(n_gyro):
            if not np.isfinite(dtheta[i, j]) or abs(dtheta[i, j]) > MAX_DTHETA_RAD:
                return -1
    return k


@kernel
def outside_window(ss, i_tmax, t_first, t_last, allowance):
    """Whether a message spanning t_first..t_last [s] lies outside the stream's plausibility
    window: t_last more than W + allowance after the stream's newest time ss[i_tmax], or t_first
    more than W before it (W = ss[SS_WINDOW] if ss has that slot, else no window; no newest time
    yet: inside)."""
    if ss.shape[0] <= SS_WINDOW:
        return False
    w, tmax = ss[SS_WINDOW], ss[i_tmax]
    if not np.isfinite(tmax) or not w < np.inf:
        return False
    return t_last - tmax > w + allowance or tmax - t_first > w


@kernel
def siru_accept(t_bus, tt, dtheta, status, ss, i_last, i_tmax, I, F, chunk, OF, OI, end, q_t,
                q_dt, q_dth, q_st, q_br, q_ve, tags):
    """Decoded siru columns (t_bus (k,) [s], tt, dtheta (k, n) [rad], status) into the stream:
    its time check (ss[i_last]: the last t_bus of the previous batch [s]; the first sample of
    this one must be later), ss[i_last] and the newest time ss[i_tmax] updated, then the SIRU
    clock (state I, F) and the append of the released samples to the gyro queue arrays q_* from
    row end (:func:`radical_rt.clock.clock_kernels.clock_push_rows`; the caller has made room for
    k·(max_bridge + 1) rows). Returns (WIRE_*, rows appended); WIRE_DUPLICATE / WIRE_BACKWARDS:
    refused by the time check, nothing changed; WIRE_JUMP: outside the plausibility window
    (:func:`outside_window`), nothing changed."""
    k = t_bus.shape[0]
    if outside_window(ss, i_tmax, t_bus[0], t_bus[k - 1], k * SPAN_PER_SAMPLE_S):
        return WIRE_JUMP, 0
    last = ss[i_last]
    if t_bus[0] == last:
        return WIRE_DUPLICATE, 0
    if t_bus[0] < last:
        return WIRE_BACKWARDS, 0
    ss[i_last] = t_bus[k - 1]
    ss[i_tmax] = max(ss[i_tmax], t_bus[k - 1])
    m = clock_push_rows(I, F, t_bus, tt, dtheta, status, chunk, OF, OI, end, q_t, q_dt, q_dth,
                        q_st, q_br, q_ve, tags)
    return WIRE_OK, m


@kernel
def siru_intake(buf, n_gyro, t_bus, tt, dtheta, status, max_k, tt_wrap, ss, i_last, i_tmax, I, F,
                chunk, OF, OI, end, q_t, q_dt, q_dth, q_st, q_br, q_ve, tags):
    """A whole plain siru message in one call: :func:`parse_siru` into the column buffers, then
    :func:`siru_accept`. Returns (WIRE_*, k, rows appended): WIRE_FALLBACK — not the plain
    layout (nothing changed); WIRE_GROW — the column buffers need k rows; WIRE_DUPLICATE /
    WIRE_BACKWARDS / WIRE_JUMP — refused by the time check (nothing changed)."""
    k = parse_siru(buf, n_gyro, t_bus, tt, dtheta, status, max_k, tt_wrap)
    if k == FALLBACK:
        return WIRE_FALLBACK, 0, 0
    if k < 0:
        return WIRE_GROW, -k - 2, 0
    code, m = siru_accept(t_bus[:k], tt[:k], dtheta[:k], status[:k], ss, i_last, i_tmax, I, F,
                          chunk, OF, OI, end, q_t, q_dt, q_dth, q_st, q_br, q_ve, tags)
    return code, k, m


class SiruWire:
    """Column buffers and scratch of :func:`parse_siru` for one stream (reused, grown on demand)."""

    def __init__(self, n_gyro: int, capacity: int = 32) -> None:
        self.n_gyro = n_gyro
        self._alloc(capacity)

    def _alloc(self, cap: int) -> None:
        self.capacity = cap
        self.t_bus, self.tt = np.empty(cap), np.empty(cap, np.int64)
        self.dtheta, self.status = np.empty((cap, self.n_gyro)), np.empty(cap, np.int64)

    def decode(self, payload: bytes):
        """(t_bus (k,), tt (k,), dtheta (k, n), status (k,)) as views of the buffers (valid until
        the next call), or None: take the general path (msgpack + decode_siru)."""
        buf = np.frombuffer(payload, np.uint8)
        while True:
            k = parse_siru(buf, self.n_gyro, self.t_bus, self.tt, self.dtheta, self.status,
                           MAX_SIRU_BATCH, SIRU_TT_WRAP)
            if k > 0:
                return self.t_bus[:k], self.tt[:k], self.dtheta[:k], self.status[:k]
            if k == FALLBACK:
                return None
            self._alloc(-k - 2)

    def grow(self, k: int) -> None:
        """Column buffers for k rows (after WIRE_GROW)."""
        self._alloc(k)

    def intake(self, clock, payload, queue, ss, i_last: int, i_tmax: int) -> tuple[int, int, int]:
        """A plain ``siru`` message straight from its bytes into ``queue`` (a
        :class:`radical_rt.engine.gyro_queue.GyroQueue`) through ``clock`` (a
        :class:`radical_rt.clock.siru_clock.SiruClock`), in one kernel call (:func:`siru_intake`: decoding,
        the stream's time check on ss[i_last] and ss[i_tmax], the clock, the queue append).
        Returns (WIRE_* status, batch length, samples appended); on any status but WIRE_OK
        nothing has changed (WIRE_FALLBACK: decode the message in Python, then :meth:`accept`)."""
        buf = np.frombuffer(payload, np.uint8)
        while True:
            I, F, chunk, out_f, out_i, tags = clock.prepare(self.capacity, queue)
            code, k, m = siru_intake(
                buf, self.n_gyro, self.t_bus, self.tt, self.dtheta, self.status, MAX_SIRU_BATCH,
                SIRU_TT_WRAP, ss, i_last, i_tmax, I, F, chunk, out_f, out_i, queue.end, queue.t,
                queue.dt, queue.dtheta, queue.status, queue.bridged, queue.var_extra, tags)
            if code != WIRE_GROW:
                break
            self.grow(k)
        if code == WIRE_OK:
            clock.taken(queue, m)
        return code, k, m

    @staticmethod
    def accept(clock, t_bus, tt, dtheta, status, queue, ss, i_last: int, i_tmax: int
               ) -> tuple[int, int]:
        """One decoded ``siru`` message (t_bus (k,) float64, tt (k,) int64, dtheta (k, n) float64,
        status (k,) int64, C-contiguous, as :func:`radical_rt.stream.packets.decode_siru` returns them)
        through the same steps as :meth:`intake` but the decoding (:func:`siru_accept`). Returns
        (WIRE_* status, samples appended); on a refusal nothing has changed."""
        I, F, chunk, out_f, out_i, tags = clock.prepare(t_bus.shape[0], queue)
        code, m = siru_accept(t_bus, tt, dtheta, status, ss, i_last, i_tmax, I, F, chunk, out_f,
                              out_i, queue.end, queue.t, queue.dt, queue.dtheta, queue.status,
                              queue.bridged, queue.var_extra, tags)
        if code == WIRE_OK:
            clock.taken(queue, m)
        return code, m
