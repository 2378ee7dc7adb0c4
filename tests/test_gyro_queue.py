"""GyroQueue: the release index (upto) against a brute-force count, through appends, releases,
compaction and growth in a seeded random sequence."""

from __future__ import annotations

import numpy as np

from radical_rt.clock import GyroBatch
from radical_rt.gyro_queue import GyroQueue


def _batch(t: np.ndarray, n: int = 4) -> GyroBatch:
    m = len(t)
    return GyroBatch(t=t, dt=np.full(m, 0.01), dtheta=np.zeros((m, n)),
                     status=np.zeros(m, np.int64), bridged=np.zeros(m, bool), var_extra=np.zeros(m))


def test_upto_matches_brute_force_through_pushes_releases_and_compaction():
    rng = np.random.default_rng(3)
    q, t_last, wm, hits = GyroQueue(4, capacity=8), 0.0, -1.0, 0
    for _ in range(4000):
        r = rng.random()
        if r < 0.3:  # append a batch (sometimes repeating the last time: equal times are allowed)
            m = int(rng.integers(1, 12))
            steps = np.where(rng.random(m) < 0.1, 0.0, rng.uniform(0.005, 0.015, m))
            t = t_last + np.cumsum(steps)
            t_last = float(t[-1])
            q.push(_batch(t))
        elif r < 0.5:  # release up to the current answer
            q.head = q.upto(wm)
        elif r < 0.51:  # everything taken at once (head past the kept answer)
            q.head = q.end
        elif r < 0.52:
            q.clear()
            t_last, wm = t_last + 1.0, t_last + 0.5
        else:  # the watermark moves forward a little, sometimes not at all, sometimes onto a sample
            pending = q.t[q.head:q.end]
            if len(pending) and rng.random() < 0.2:
                wm = max(wm, float(rng.choice(pending)))
            else:
                wm += float(rng.choice([0.0, 0.001, 0.004, 0.03]))
        memo_before = q._memo
        z = q.upto(wm)
        hits += memo_before is not None and q._memo is memo_before
        expect = q.head + int(np.count_nonzero(q.t[q.head:q.end] <= wm))
        assert z == expect, (z, expect, q.head, q.end, wm)
    assert hits > 500  # the kept answer was used (and checked) often
