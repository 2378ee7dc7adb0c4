"""The FDI's history (docs/fdi.md §3.1): the recent gyro samples and tracker samples in compact
blocks, and the engine snapshots the hypothesis bank and the rollback start from. Used by
:class:`radical_rt.fdi.monitor.FaultMonitor`; the bank's kernels read the blocks in place."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radical_rt.fdi.fdi_bank_propagate import append_rows


class SampleBuffer:
    """Recent gyro samples as the engine received them, time order, copied into growing blocks
    (one float block t, dt, var_extra, dθ; one int block status; one bool block bridged) with a
    moving start: about 70 bytes per sample, so ``BUFFER_S`` of history costs a few MB per vehicle
    (keeping the clock's batches themselves cost about 1.5 kB per sample, and the history grew
    with the stream until a late compaction)."""

    _COLS = 3  # t, dt, var_extra; then the n increments

    def __init__(self) -> None:
        self.clear()

    def clear(self) -> None:
        self._f = np.empty((0, 0))
        self._i = np.empty(0, np.int64)
        self._b = np.empty(0, np.bool_)
        self.i0 = self.end = 0

    def __len__(self) -> int:
        return self.end - self.i0

    def append(self, arrays, a: int = 0, z: int | None = None) -> None:
        """Copy rows a..z−1 (default: all) of the sample arrays (t, dt, dθ, status, bridged,
        var_extra)."""
        t, dt, dth, status, bridged, var_extra = arrays
        z = len(t) if z is None else z
        m = z - a
        if m <= 0:
            return
        self.reserve(m, dth.shape[1])
        append_rows(self._f, self._i, self._b, self.end, t, dt, var_extra, dth, status, bridged,
                    a, z)
        self.end += m

    def reserve(self, m: int, n: int) -> None:
        """Room for m more samples of n gyros after ``end`` (the compiled release appends them
        itself with :func:`radical_rt.fdi.fdi_bank_propagate.append_rows`, then advances ``end``)."""
        if self._f.shape[1] != self._COLS + n or self.end + m > len(self._i):
            self._make_room(m, n)

    def _make_room(self, m: int, n: int) -> None:
        """Move the kept samples to the front; grow (×2) if they and m more do not fit."""
        keep = self.end - self.i0 if self._f.shape[1] == self._COLS + n else 0
        cap = max(len(self._i), 1024)
        while keep + m > cap // 2 and keep + m > 1024:
            cap *= 2
        if cap != len(self._i) or self._f.shape[1] != self._COLS + n:
            f, i, b = np.empty((cap, self._COLS + n)), np.empty(cap, np.int64), np.empty(cap, np.bool_)
        else:
            f, i, b = self._f, self._i, self._b
        if keep:
            src = slice(self.i0, self.i0 + keep)
            f[:keep], i[:keep], b[:keep] = self._f[src], self._i[src], self._b[src]
        self._f, self._i, self._b = f, i, b
        self.i0, self.end = 0, keep

    def drop_before(self, t_min: float) -> None:
        """Forget the samples with t < t_min."""
        t = self._f[self.i0:self.end, 0] if self.end > self.i0 else None
        if t is not None:
            self.i0 += int(np.searchsorted(t, t_min, side="left"))

    def span(self, t_after: float, t_upto: float):
        """The samples with t_after < t ≤ t_upto, without a copy, as (f, status, bridged, a, z):
        rows a..z−1 of the float block f (m, 3 + n) (t [s], dt [s], var_extra [rad²], dθ [rad]),
        the int64 block of status bits and the bool block; None if there are none. Valid until
        the next append or drop."""
        if self.end == self.i0:
            return None
        t = self._f[self.i0:self.end, 0]
        a = self.i0 + int(np.searchsorted(t, t_after, side="right"))
        z = self.i0 + int(np.searchsorted(t, t_upto, side="right"))
        if z <= a:
            return None
        return self._f, self._i, self._b, a, z

    def get_state(self, rows: bool = True) -> dict[str, np.ndarray]:
        """The rows in use, copied (checkpoints): f (m, 3 + n), status (m,), bridged (m,);
        ``rows=False``: none of them (m = 0)."""
        s = slice(self.i0, self.end) if rows else slice(0, 0)
        return {"f": self._f[s].copy(), "status": self._i[s].copy(), "bridged": self._b[s].copy()}

    def set_state(self, st: dict[str, np.ndarray]) -> None:
        """Put :meth:`get_state` rows back (validated by the caller: time order, shapes)."""
        f = np.asarray(st["f"], np.float64)
        self.clear()
        if len(f):
            self._f, self._i = f.copy(), np.asarray(st["status"], np.int64).copy()
            self._b = np.asarray(st["bridged"], np.bool_).copy()
            self.end = len(f)

    def blocks(self):
        """(f, status, bridged, i0, end): the blocks of :meth:`span` and the rows in use."""
        return self._f, self._i, self._b, self.i0, self.end


class TrackerBuffer:
    """The valid tracker samples the engine received, in order, numbered by consecutive sequence
    numbers, as rows of two growing arrays with a moving start: float rows (epoch [s, gyro time
    line], q_st_from_inertial (4,) scalar last) and int rows (seq, tracker j = 1 | 2, n_stars),
    48 bytes per sample. Indexing gives the bank's tuple ``(seq, t_epoch, j, q (4,) copy,
    n_stars)`` (negative indices from the end). A checkpoint takes the rows as five columns
    (:meth:`get_state`), a copy of a few arrays instead of one tuple per sample."""

    def __init__(self) -> None:
        self.clear()

    def clear(self) -> None:
        self._f, self._i = np.empty((256, 5)), np.empty((256, 3), np.int64)
        self.i0 = self.end = 0

    def __len__(self) -> int:
        return self.end - self.i0

    def append(self, seq: int, t_epoch: float, j: int, q, n_stars: int) -> None:
        """One sample (q copied); ``seq`` follows the last one."""
        if self.end == len(self._i):
            self._make_room()
        r = self.end
        f = self._f[r]
        f[0] = t_epoch
        f[1:5] = q
        self._i[r] = (seq, j, n_stars)
        self.end = r + 1

    def reserve(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """Room for m more rows after ``end`` (the engine's compiled release appends the samples
        it completes itself, then the owner advances ``end``); returns the float and int arrays."""
        if self.end + m > len(self._i):
            self._make_room(m)
        return self._f, self._i

    def _make_room(self, m: int = 1) -> None:
        """Move the kept rows to the front; grow (×2) while they and m more fill half the
        arrays."""
        keep, cap = self.end - self.i0, len(self._i)
        while keep + m > cap // 2:
            cap *= 2
        f, i = np.empty((cap, 5)), np.empty((cap, 3), np.int64)
        f[:keep], i[:keep] = self._f[self.i0:self.end], self._i[self.i0:self.end]
        self._f, self._i, self.i0, self.end = f, i, 0, keep

    def __getitem__(self, k: int) -> tuple:
        n = self.end - self.i0
        if k < 0:
            k += n
        if not 0 <= k < n:
            raise IndexError("tracker sample index out of range")
        r = self.i0 + k
        seq, j, n_stars = self._i[r].tolist()
        return seq, float(self._f[r, 0]), j, self._f[r, 1:5].copy(), n_stars

    def drop_through(self, seq: int) -> None:
        """Forget the samples numbered ≤ seq."""
        if self.end > self.i0:
            first = int(self._i[self.i0, 0])
            self.i0 = min(self.end, self.i0 + max(0, seq - first + 1))

    def get_state(self, rows: bool = True) -> dict[str, np.ndarray]:
        """The rows in use as copied columns (checkpoints): seq, t, tracker, n_stars (m,), q
        (m, 4); ``rows=False``: none of them (m = 0)."""
        s = slice(self.i0, self.end) if rows else slice(0, 0)
        f, i = self._f[s], self._i[s]
        return {"seq": i[:, 0].copy(), "t": f[:, 0].copy(), "tracker": i[:, 1].copy(),
                "q": f[:, 1:5].copy(), "n_stars": i[:, 2].copy()}

    def set_state(self, st: dict[str, np.ndarray]) -> None:
        """Put :meth:`get_state` columns back (validated by the caller: consecutive numbers,
        ranges, shapes)."""
        m = len(st["seq"])
        cap = max(2 * m, 256)
        self._f, self._i = np.empty((cap, 5)), np.empty((cap, 3), np.int64)
        self._f[:m, 0], self._f[:m, 1:5] = st["t"], st["q"]
        self._i[:m, 0], self._i[:m, 1], self._i[:m, 2] = st["seq"], st["tracker"], st["n_stars"]
        self.i0, self.end = 0, m


@dataclass
class Snapshot:
    """Engine state at a window close (after the correction), for the bank and the rollback."""

    t: float  # time of the last propagated sample
    trk_seq: int  # last tracker sample already applied
    gen: tuple  # (cold starts, warm starts, attitude inits): a change invalidates the snapshot
    q: np.ndarray
    omega: np.ndarray
    xp: np.ndarray
    U: np.ndarray
    d: np.ndarray
    N: np.ndarray


__all__ = ["SampleBuffer", "Snapshot", "TrackerBuffer"]
