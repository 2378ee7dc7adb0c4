"""SIRU oscillator, time-tag counter and bus reads (CONTRACT §1.5, notes/rimu.md §13.2).

SIRU sample k is taken at true bus time ``t_k = t_start + phase + k·T·(1+ε) + jitter_k`` (k ≥ 0;
k = −1 only bounds sample 0's interval). Its counter ``tt_k = (tt0 + 10000·k) mod 2**32`` counts
SIRU oscillator ticks; a counter reset at time r restarts it at 0 for the first sample with
``t_k ≥ r``. The bus reads at ``τ_j = t_start + j·T_bus + jitter_j`` (j ≥ 1) and gets the latest
sample with ``t_k ≤ τ_j``. Jitters are Gaussian truncated at ±4σ, drawn in index order from their
own streams, so the result does not depend on how the run is chunked. Times in s.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from radical_rt.conventions import SIRU_TT_TICK_S, SIRU_TT_WRAP


def truncated_normal(rng: np.random.Generator, sigma: float, n: int) -> np.ndarray:
    """n draws of N(0, σ²) clipped to ±4σ (s)."""
    return np.clip(rng.standard_normal(n), -4.0, 4.0) * sigma


class Samples(NamedTuple):
    """SIRU samples (m,): index k, interval start t_{k−1} (s), time t_k (s), counter tt, and
    ``reset`` (True where a counter reset took effect)."""

    k: np.ndarray
    t_prev: np.ndarray
    t: np.ndarray
    tt: np.ndarray
    reset: np.ndarray


class SiruClock:
    """Generates SIRU sample times and counters in order, as far as the bus needs them.

    ``siru``: the scenario's [siru] table; ``t_start``: bus time of the run start (s);
    ``rng``: the sample-jitter stream.
    """

    def __init__(self, siru: dict, t_start: float, rng: np.random.Generator):
        self.T = siru["period_s"] * (1.0 + siru["eps_ppm"] * 1e-6)
        self.t_first = t_start + siru["phase_s"]
        self.sigma = siru["sample_jitter_s"]
        self.ticks = int(round(siru["period_s"] / SIRU_TT_TICK_S))
        self.rng = rng
        self.resets = sorted(t_start + r for r in siru["tt_reset_s"])
        self.tt_base, self.tt_base_k = int(siru["tt0"]), 0
        self._k_next = 0
        self._pend_k = np.empty(0, dtype=np.int64)
        self._pend_t = np.empty(0)
        self.t_last = self.t_first - self.T + truncated_normal(rng, self.sigma, 1)[0]  # t_{-1}

    def _generate(self, t_end: float) -> None:
        """Draw samples up to the first whose nominal time exceeds t_end by more than 4σ."""
        k_hi = int(np.floor((t_end + 4.0 * self.sigma - self.t_first) / self.T)) + 1
        if k_hi <= self._k_next:
            return
        k = np.arange(self._k_next, k_hi, dtype=np.int64)
        t = self.t_first + k * self.T + truncated_normal(self.rng, self.sigma, k.size)
        self._pend_k = np.concatenate([self._pend_k, k])
        self._pend_t = np.concatenate([self._pend_t, t])
        self._k_next = k_hi

    def take_through(self, t_end: float) -> Samples:
        """All not yet taken samples with t_k ≤ t_end, in order (see :class:`Samples`)."""
        self._generate(t_end)
        m = int(np.searchsorted(self._pend_t, t_end, side="right"))
        k, t = self._pend_k[:m], self._pend_t[:m]
        self._pend_k, self._pend_t = self._pend_k[m:], self._pend_t[m:]
        t_prev = np.concatenate([[self.t_last], t[:-1]]) if m else np.empty(0)
        if m:
            self.t_last = float(t[-1])
        tt, reset = self._tt(k, t)
        return Samples(k, t_prev, t, tt, reset)

    def _tt(self, k: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Counter values (m,) with resets applied at the first sample at or after each reset,
        and the mask (m,) of the samples where a reset took effect."""
        tt = np.empty(k.size, dtype=np.int64)
        reset = np.zeros(k.size, dtype=bool)
        start = 0
        while self.resets and (i := int(np.searchsorted(t, self.resets[0]))) < k.size:
            tt[start:i] = (self.tt_base + self.ticks * (k[start:i] - self.tt_base_k)) % SIRU_TT_WRAP
            self.tt_base, self.tt_base_k, start = 0, int(k[i]), i
            reset[i] = True
            while self.resets and self.resets[0] <= t[i]:
                self.resets.pop(0)
        tt[start:] = (self.tt_base + self.ticks * (k[start:] - self.tt_base_k)) % SIRU_TT_WRAP
        return tt, reset


class BusReads:
    """Bus read times τ_j (j ≥ 1) for consecutive index ranges; ``rng`` is the read-jitter stream."""

    def __init__(self, siru: dict, t_start: float, rng: np.random.Generator):
        self.P = siru["bus_period_s"]
        self.sigma = siru["read_jitter_s"]
        self.t_start = t_start
        self.rng = rng
        self._j_next = 1

    def times(self, j0: int, j1: int) -> np.ndarray:
        """τ_j for j in [max(j0, 1), j1) (s); ranges must be requested in order, without holes."""
        j0 = max(j0, 1)
        assert j0 == self._j_next, "bus reads must be requested in order"
        self._j_next = max(j1, j0)
        j = np.arange(j0, j1)
        return self.t_start + j * self.P + truncated_normal(self.rng, self.sigma, j.size)


def latest_sample(sample_t: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Index (n,) into sample_t (ascending) of the latest sample with t ≤ τ for each read; −1 if none."""
    return np.searchsorted(sample_t, tau, side="right") - 1


def read_counts(k_read: np.ndarray, k_prev: int | None) -> tuple[int, int, int]:
    """(n_reads, n_repeated, n_missing) of consecutive reads of sample indices k_read (n,).

    ``k_prev`` is the sample index of the read before (None at the start of an archive). A read
    repeats when it returns the same sample; samples skipped between reads are missing.
    """
    if k_read.size == 0:
        return 0, 0, 0
    seq = k_read if k_prev is None else np.concatenate([[k_prev], k_read])
    d = np.diff(seq)
    return int(k_read.size), int(np.sum(d == 0)), int(np.sum(np.maximum(d - 1, 0)))
