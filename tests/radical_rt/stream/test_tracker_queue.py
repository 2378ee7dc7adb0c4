"""The tracker queue and its compiled intake (radical_rt.stream.tracker_queue) against the stream's
earlier Python logic (a heap ordered by epoch, tracker, arrival; the same time checks, late test
and release test), and the compiled decoding against msgpack + decode_tracker."""

from __future__ import annotations

import heapq
import math

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radical_rt.stream.packets import MAX_N_STARS, InputError, decode_tracker, unpack
from radical_rt.stream.tracker_queue import (
    IN_BACKWARDS,
    IN_DUPLICATE,
    IN_FALLBACK,
    IN_FULL,
    IN_IDLE,
    IN_RELEASE,
    PLAN_DEFERRED,
    PLAN_GO,
    PLAN_NOTHING,
    SI_LATE,
    SS_RELEASED,
    SS_T_MAX,
    TrackerQueue,
    parse_tracker,
    release_plan,
    tracker_accept,
    tracker_intake,
)

LAT, SLACK, WINDOW = 0.115, 0.05, 10


class HeapModel:
    """The stream's former Python implementation (heap of tuples), for comparison."""

    def __init__(self) -> None:
        self.heap, self.seq, self.late = [], 0, 0
        self.last = {1: -math.inf, 2: -math.inf}
        self.t_max = self.released = -math.inf

    def accept(self, j, t, q, n, valid):
        if t == self.last[j]:
            return IN_DUPLICATE
        if t < self.last[j]:
            return IN_BACKWARDS
        self.last[j] = t
        self.t_max = max(self.t_max, t)
        epoch = t - LAT
        if epoch < self.released:
            self.late += 1
        else:
            self.seq += 1
            heapq.heappush(self.heap, (epoch, j, self.seq, tuple(q), n, valid))
        return None

    def plan(self, wm, gq_t, a, b, acc0, defer):
        due = []
        while self.heap and self.heap[0][0] <= wm:
            due.append(heapq.heappop(self.heap))
            self.released = max(self.released, due[-1][0])
        z = a + int(np.searchsorted(gq_t[a:b], wm, side="right"))
        if z == a and not due:
            return PLAN_NOTHING, due, z
        if defer and not due and acc0 + (z - a) < WINDOW:
            self.released = max(self.released, float(gq_t[z - 1]))
            return PLAN_DEFERRED, due, z
        if z > a:
            self.released = max(self.released, float(gq_t[z - 1]))
        return PLAN_GO, due, z


def test_queue_matches_the_heap_through_random_arrivals():
    """Seeded random tracker arrivals (jittered, out of order across trackers, duplicates, steps
    back, late samples) interleaved with gyro releases: the same codes, the same released rows in
    the same order, the same released epoch, late count and t_max as the heap."""
    rng = np.random.default_rng(11)
    tq, model = TrackerQueue(capacity=1), HeapModel()  # small: growth and compaction happen
    gq_t = np.cumsum(np.full(20000, 0.01))
    gq_head, gq_end, acc0, t_clock, last = 0, 0, 0, 0.5, {1: 0.0, 2: 0.0}
    n_go = n_late = n_refused = 0
    for _ in range(6000):
        r = rng.random()
        if r < 0.45:  # a tracker sample
            j = int(rng.integers(1, 3))
            u = rng.random()
            if u < 0.05:  # an exact repeat
                t = last[j]
            elif u < 0.1:  # a step back
                t = round(last[j] - 0.05, 6)
            elif u < 0.15 and last[3 - j] > last[j]:  # the other tracker's time: equal epochs
                t = last[3 - j]
            else:  # on time, early or delayed
                t = round(t_clock + float(rng.normal(0.0, 0.04)), 6)
            last[j] = t
            q = rng.normal(size=4)
            q /= np.linalg.norm(q)
            n, valid = int(rng.integers(0, 12)), bool(rng.random() < 0.9)
            want = model.accept(j, t, q, n, valid)
            while True:
                code = tracker_accept(t, q, n, valid, j, LAT, SLACK, tq.ss, tq.si, tq.ev_f,
                                      tq.ev_i, gq_t, gq_head, gq_end, acc0, WINDOW)
                if code != IN_FULL:
                    break
                tq.grow()
            if want is not None:
                assert code == want
                n_refused += 1
                continue
            assert code in (IN_IDLE, IN_RELEASE)
            # the stream then releases with defer (IN_RELEASE) or has nothing to do (IN_IDLE)
            wm = model.t_max - LAT - SLACK
            want_plan, due, z_want = model.plan(wm, gq_t, gq_head, gq_end, acc0, defer=True)
            assert (want_plan == PLAN_GO) == (code == IN_RELEASE)
            if code == IN_RELEASE:
                plan, e1, z = release_plan(tq.ss, tq.si, tq.ev_f, gq_t, gq_head, gq_end, wm,
                                           acc0, WINDOW, True)
                assert (plan, z) == (want_plan, z_want)
                got = [(ev[1], ev[0], tuple(ev[2]), ev[3], ev[4]) for ev in tq.block(e1)]
                assert got == [(d[0], d[1], d[3], d[4], d[5]) for d in due]
                n_go += len(got)
                acc0 = (acc0 + z - gq_head) % WINDOW
                gq_head = z
        else:  # the SIRU side: samples arrive, a release at the watermark
            t_clock += 0.03
            gq_end = max(gq_end, min(len(gq_t), int(np.searchsorted(gq_t, t_clock))
                                     - int(rng.integers(0, 10))))
            model.t_max = max(model.t_max, float(gq_t[gq_end - 1]))
            tq.ss[SS_T_MAX] = max(tq.ss[SS_T_MAX], gq_t[gq_end - 1])
            wm = model.t_max - LAT - SLACK
            defer = bool(rng.random() < 0.3)
            want_plan, due, z_want = model.plan(wm, gq_t, gq_head, gq_end, acc0, defer)
            plan, e1, z = release_plan(tq.ss, tq.si, tq.ev_f, gq_t, gq_head, gq_end, wm, acc0,
                                       WINDOW, defer)
            assert (plan, z) == (want_plan, z_want)
            if plan == PLAN_GO:
                blk = tq.block(e1)
                got = [(ev[1], ev[0], tuple(ev[2]), ev[3], ev[4]) for ev in blk]
                assert got == [(d[0], d[1], d[3], d[4], d[5]) for d in due]
                n_go += len(got)
                acc0 = (acc0 + z - gq_head) % WINDOW
                gq_head = z
        assert tq.ss[SS_RELEASED] == model.released and tq.ss[SS_T_MAX] == model.t_max
        assert tq.si[SI_LATE] == model.late
        n_late = model.late
    assert n_go > 1000 and n_late > 20 and n_refused > 100 and tq.ev_f.shape[0] > 1


def _plain(**changes):
    m = {"v": 1, "t_bus": 1234.5, "q": [0.5, 0.5, 0.5, 0.5], "n_stars": 9, "valid": True}
    m.update(changes)
    return {k: v for k, v in m.items() if v is not None}


def _general(payload):
    try:
        return decode_tracker(unpack(payload))
    except InputError as exc:
        return exc.reason


@settings(max_examples=300, deadline=None)
@given(st.floats(-1e9, 1e9), st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4),
       st.integers(0, MAX_N_STARS), st.booleans(), st.permutations(["v", "t_bus", "q", "n_stars", "valid"]),
       st.floats(0.9995, 1.0005))
def test_plain_messages_decode_as_the_general_path(t, q, n, valid, order, norm):
    qv = np.array(q)
    if not np.linalg.norm(qv) > 0.1:
        qv = np.array([0.0, 0.0, 0.0, 1.0])
    qv = (qv / np.linalg.norm(qv) * norm).tolist()
    m = _plain(t_bus=t, q=qv, n_stars=n, valid=valid)
    payload = msgpack.packb({k: m[k] for k in order})
    q_out = np.zeros(4)
    ok, t_f, n_f, valid_f = parse_tracker(np.frombuffer(payload, np.uint8), q_out)
    want = _general(payload)
    assert ok and not isinstance(want, str)
    assert (t_f, n_f, valid_f) == (want[0], want[2], want[3])
    assert np.array_equal(q_out, want[1])


@pytest.mark.parametrize("payload", [
    msgpack.packb(_plain(q=[0.5, 0.5, 0.5, 0.6])),  # not unit: the general path names it
    msgpack.packb(_plain(t_bus=math.nan)),
    msgpack.packb(_plain(n_stars=-1)), msgpack.packb(_plain(n_stars=MAX_N_STARS + 1)),
    msgpack.packb(_plain(valid=1)),
    msgpack.packb(_plain(q=[0.5, 0.5, 0.5])),
    msgpack.packb(_plain(v=2)),
    msgpack.packb(_plain(valid=None)),
    msgpack.packb(_plain(extra=1)),  # valid, but not the plain layout
    msgpack.packb(_plain(t_bus=1234)),  # an integer time: valid, decoded by the general path
    msgpack.packb(_plain(q=[0.5, 0.5, 0.5, 0.5]), use_single_float=True),
    msgpack.packb(_plain()) + b"\x00",
    msgpack.packb(_plain())[:-3],
    b"",
])
def test_other_messages_fall_back(payload):
    assert not parse_tracker(np.frombuffer(payload, np.uint8), np.zeros(4))[0]


def test_corrupted_payloads_never_accepted_differently():
    rng = np.random.default_rng(5)
    good = msgpack.packb(_plain(q=[0.1, -0.7, 0.7, float(np.sqrt(1 - 0.99))]))
    accepted = fell_back = 0
    for _ in range(3000):
        buf = bytearray(good)
        for _ in range(int(rng.integers(1, 3))):
            buf[int(rng.integers(len(buf)))] = int(rng.integers(256))
        payload = bytes(buf)
        q_out = np.zeros(4)
        ok, t, n, valid = parse_tracker(np.frombuffer(payload, np.uint8), q_out)
        if not ok:
            fell_back += 1
            continue
        accepted += 1
        want = _general(payload)
        assert not isinstance(want, str)
        assert (t, n, valid) == (want[0], want[2], want[3]) and np.array_equal(q_out, want[1])
    assert accepted > 100 and fell_back > 100


def test_intake_refusals_change_nothing():
    tq = TrackerQueue()
    gq_t = np.zeros(0)
    args = (1, LAT, SLACK, tq.ss, tq.si, tq.ev_f, tq.ev_i, gq_t, 0, 0, 0, WINDOW, tq.q_work)
    buf = np.frombuffer(msgpack.packb(_plain()), np.uint8)
    assert tracker_intake(buf, *args) in (IN_IDLE, IN_RELEASE)
    before = (tq.ss.copy(), tq.si.copy(), tq.ev_f.copy())
    assert tracker_intake(buf, *args) == IN_DUPLICATE
    earlier = np.frombuffer(msgpack.packb(_plain(t_bus=1000.0)), np.uint8)
    assert tracker_intake(earlier, *args) == IN_BACKWARDS
    odd = np.frombuffer(msgpack.packb(_plain(extra=1)), np.uint8)
    assert tracker_intake(odd, *args) == IN_FALLBACK
    assert np.array_equal(tq.si, before[1]) and np.array_equal(tq.ev_f, before[2])
    assert np.array_equal(tq.ss[:4], before[0][:4])  # (ss[4] only notes the refused t_bus)


@pytest.mark.parametrize("as_map", [False, True])
def test_stream_grows_the_queue_for_waiting_samples(as_map):
    """Tracker samples with no gyro data yet pile up: the stream grows a one-row queue as needed,
    whether the compiled intake (bytes) or the general path (maps) takes them."""
    from radical_rt.stream.processor import StreamProcessor
    sp = StreamProcessor(reorder_slack_s=1e4)  # nothing becomes due
    sp.tracker_q = TrackerQueue(capacity=1)
    sp.begin_stream()
    for k in range(40):
        m = _plain(t_bus=1000.0 + 0.1 * k)
        sp.feed("st1" if k % 2 else "st2", m if as_map else msgpack.packb(m))
    assert len(sp.tracker_q) == 40 and sp.tracker_q.ev_f.shape[0] >= 40 and not sp.rejected
    epochs = sp.tracker_q.ev_f[:40, 0]
    assert np.all(np.diff(epochs) > 0)
