"""The FDI's tracker history (radical_rt.fdi.fdi_history.TrackerBuffer) against a plain deque of
the tuples it replaced: appends past several growths and compactions, drops by sequence number,
indexing from both ends, and the checkpoint columns round trip."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest

from radical_rt.fdi.fdi_history import TrackerBuffer


def _same(buf: TrackerBuffer, ref: deque) -> None:
    assert len(buf) == len(ref)
    for k in range(-len(ref), len(ref)):
        a, b = buf[k], ref[k]
        assert a[:3] == b[:3] and a[4] == b[4] and np.array_equal(a[3], b[3])
        assert type(a[0]) is int and type(a[1]) is float


def test_tracker_buffer_follows_a_deque():
    rng = np.random.default_rng(7)
    buf, ref, seq = TrackerBuffer(), deque(), 0
    for step in range(40):
        for _ in range(int(rng.integers(0, 200))):
            seq += 1
            q = rng.normal(size=4)
            q /= np.linalg.norm(q)
            row = (seq, float(seq * 0.05 + rng.uniform(0, 0.01)), int(rng.integers(1, 3)), q,
                   int(rng.integers(0, 30)))
            buf.append(*row)
            ref.append((row[0], row[1], row[2], q.copy(), row[4]))
        keep = seq - int(rng.integers(0, 300))
        buf.drop_through(keep)
        while ref and ref[0][0] <= keep:
            ref.popleft()
        _same(buf, ref)
        if step % 7 == 0:  # through a checkpoint's columns
            st = buf.get_state()
            assert st["q"].shape == (len(ref), 4) and st["seq"].dtype == np.int64
            buf = TrackerBuffer()
            buf.set_state(st)
            _same(buf, ref)
    assert TrackerBuffer().get_state()["seq"].shape == (0,)
    assert buf.get_state(rows=False)["q"].shape == (0, 4)
    with pytest.raises(IndexError):
        buf[len(ref)]
    buf.clear()
    assert len(buf) == 0
    buf.drop_through(10**9)  # nothing to drop: no error
