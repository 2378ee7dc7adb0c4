"""Reconstructed gyro samples waiting for their release to the engine (a FIFO in flat arrays).

The stream processor holds samples back until the watermark passes them
(:mod:`radical_rt.stream.processor`); the engine then takes a range of them in one call
(:meth:`radical_rt.engine.filter.Engine.release`). Keeping the samples in one set of contiguous arrays,
instead of a list of the clock's batches, makes a release an index range (no slicing or
concatenation per event), and the not-yet-released samples one view for the low-latency
prediction of sample-triggered telemetry.
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt._jit import kernel
from radical_rt.clock import clock_layout as L
from radical_rt.clock.clock_timing import pending_read
from radical_rt.clock.siru_clock import GyroBatch
from radical_rt.kernels.propagate import predict_now


class GyroQueue:
    """Samples ``head``..``end``−1 of the arrays t, dt [s], dtheta (·, n) [rad], status (int bits),
    bridged (bool), var_extra [rad²] are pending, in time order."""

    def __init__(self, n_gyro: int, capacity: int = 2048) -> None:
        self.n_gyro = n_gyro
        self._alloc(capacity)
        self.head = self.end = 0

    def _alloc(self, cap: int) -> None:
        self.t, self.dt, self.var_extra = np.empty(cap), np.empty(cap), np.empty(cap)
        self.dtheta = np.empty((cap, self.n_gyro))
        self.status = np.empty(cap, np.int64)
        self.bridged = np.empty(cap, np.bool_)

    def __len__(self) -> int:
        return self.end - self.head

    def clear(self) -> None:
        self.head = self.end = 0

    def push(self, b: GyroBatch) -> None:
        """Append a batch of samples (later than the pending ones)."""
        m = len(b.t)
        self.reserve(m)
        s = slice(self.end, self.end + m)
        self.t[s], self.dt[s], self.dtheta[s] = b.t, b.dt, b.dtheta
        self.status[s], self.bridged[s], self.var_extra[s] = b.status, b.bridged, b.var_extra
        self.end += m

    def reserve(self, m: int) -> None:
        """Make room for m more samples after ``end`` (moves or grows the arrays if needed)."""
        if self.end + m > len(self.t):
            self._make_room(m)

    def _make_room(self, m: int) -> None:
        """Move the pending samples to the front; double the capacity until m more fit."""
        keep, cap = len(self), len(self.t)
        while keep + m > cap:
            cap *= 2
        src = slice(self.head, self.end)
        old = self.arrays()
        if cap != len(self.t):
            self._alloc(cap)
        for dst, a in zip(self.arrays(), old, strict=True):
            dst[:keep] = a[src]  # copies (overlapping moves are safe with numpy assignment)
        self.head, self.end = 0, keep

    def arrays(self) -> tuple[np.ndarray, ...]:
        """The whole arrays (t, dt, dtheta, status, bridged, var_extra): index with head..end."""
        return self.t, self.dt, self.dtheta, self.status, self.bridged, self.var_extra


@kernel
def predict_pending(dtheta, dt, status, a, b, t_now, clock_I, clock_F, excluded, xp, A, Gp, q,
                    omega, work):
    """The attitude of sample-triggered telemetry in one call: q (4,) q_body_from_inertial and
    omega (3,) [rad/s] (in place, from the filter's estimate) propagated through the queue's
    pending samples a..b−1 (dtheta (m, n), dt, status) and, when the SIRU clock (state arrays
    clock_I, clock_F) holds back a read that is probably the next sample, through that read as
    one more sample one estimated period later (:func:`radical_rt.kernels.propagate.predict_now`).
    work: a radical_rt.kernels.propagate.SampleWork (scratch). Returns the time of the
    prediction [s]: t_now, plus the period if the held-back read was used (not when t_now is not
    finite)."""
    has, pend_status, period = pending_read(clock_I, clock_F)
    use = has and math.isfinite(t_now)
    n = dtheta.shape[1]
    dp = L.DA + n
    predict_now(dtheta, dt, status, a, b, clock_F[dp:dp + n], pend_status, period, use, excluded,
                xp, A, Gp, q, omega, work)
    return t_now + period if use else t_now
