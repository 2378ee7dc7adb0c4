"""SIRU oscillator, time-tag counter and bus reads (CONTRACT §1.5, notes/rimu.md §13.2).

SIRU sample k is taken at true bus time ``t_k = t_start + phase + k·T·(1+ε) + jitter_k`` (k ≥ 0;
k = −1 only bounds sample 0's interval). Its counter ``tt_k = (tt0 + 10000·k) mod 2**32`` counts
SIRU oscillator ticks; a counter reset at time r restarts it at 0 for the first sample with
``t_k ≥ r``. The bus reads at its ticks j ≥ 1 and gets the latest sample with ``t_k ≤`` the read
instant. With ``tag_mode = "read"`` (default) the read instant is ``τ_j = t_start + j·T_bus +
jitter_j`` and is its own tag ``t_bus = τ_j``; with ``tag_mode = "tick"`` the tag is the nominal
tick ``t_bus = t_start + j·T_bus`` and the read instant is ``tick − read_offset − jitter_j``,
clipped so that it is never later than its tag (CONTRACT §1.5: ``t_bus ≥ t_k``). Occasional late
reads (probability ``late_read_prob``) are delayed by U(0, ``late_read_max_s``), then clipped the
same way in tick mode. The sample jitter is Gaussian truncated at ±4σ; the read jitter is
Gaussian (±4σ), uniform (same 1σ) or Student-t (same 1σ, ±min(20σ, T_bus/5)). Every draw comes
in index order from its own stream, so the result does not depend on how the run is chunked.
Times in s.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from radical_rt.contract.conventions import SIRU_TT_TICK_S, SIRU_TT_WRAP

from .schema import siru_timing

#: Student-t read jitter: clipped at this many σ (and at bus_period/5).
STUDENT_T_CLIP_SIGMA = 20.0


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


class Reads(NamedTuple):
    """Bus reads (n,): tag ``t_bus`` (s), read instant ``t_read`` (s, ≤ t_bus in tick mode),
    ``late`` (a late read) and ``clipped`` (tick mode: the read instant was moved to its tag)."""

    t_bus: np.ndarray
    t_read: np.ndarray
    late: np.ndarray
    clipped: np.ndarray


def jitter_clip_s(siru: dict) -> float:
    """Largest |read jitter| (s) of the scenario's distribution: 4σ (Gaussian), √3σ (uniform),
    min(20σ, bus_period/5) (Student-t)."""
    sigma, dist = siru["read_jitter_s"], siru_timing(siru)["read_jitter_dist"]
    if dist == "uniform":
        return float(np.sqrt(3.0) * sigma)
    if dist == "student_t":
        return min(STUDENT_T_CLIP_SIGMA * sigma, siru["bus_period_s"] / 5.0)
    return 4.0 * sigma


class BusReads:
    """Bus reads for consecutive index ranges j ≥ 1 (see the module docstring).

    ``rng`` is the Gaussian read-jitter stream (``siru.read_jitter``, the only stream the
    defaults use); ``streams(name)`` gives the other named streams (``siru.read_jitter.uniform``,
    ``siru.read_jitter.student_t``, ``siru.late_read``), needed only when those knobs are set.
    """

    def __init__(self, siru: dict, t_start: float, rng: np.random.Generator,
                 streams: Callable[[str], np.random.Generator] | None = None):
        self.P = siru["bus_period_s"]
        self.sigma = siru["read_jitter_s"]
        self.t_start = t_start
        tm = siru_timing(siru)
        self.tick_mode = tm["tag_mode"] == "tick"
        self.offset = tm["read_offset_s"]
        self.dist, self.dof = tm["read_jitter_dist"], tm["read_jitter_dof"]
        self.clip = jitter_clip_s(siru)
        self.late_prob, self.late_max = tm["late_read_prob"], tm["late_read_max_s"]
        self.late_rng: np.random.Generator | None = None
        if self.dist != "gaussian" or self.late_prob > 0:
            if streams is None:
                raise ValueError("BusReads: these read-timing knobs need the named streams")
            rng = streams(f"siru.read_jitter.{self.dist}") if self.dist != "gaussian" else rng
            self.late_rng = streams("siru.late_read") if self.late_prob > 0 else None
        self.rng = rng
        self._j_next = 1

    def _jitter(self, n: int) -> np.ndarray:
        """n read-jitter draws (s), 1σ = read_jitter_s."""
        if self.dist == "uniform":
            return self.rng.uniform(-self.clip, self.clip, n)
        if self.dist == "student_t":
            scale = self.sigma / np.sqrt(self.dof / (self.dof - 2.0))
            return np.clip(self.rng.standard_t(self.dof, n) * scale, -self.clip, self.clip)
        return truncated_normal(self.rng, self.sigma, n)

    def read(self, j0: int, j1: int) -> Reads:
        """The reads of ticks j in [max(j0, 1), j1); ranges must be requested in order, without
        holes."""
        j0 = max(j0, 1)
        assert j0 == self._j_next, "bus reads must be requested in order"
        self._j_next = max(j1, j0)
        j = np.arange(j0, j1)
        tick = self.t_start + j * self.P
        t = tick - self.offset - self._jitter(j.size) if self.tick_mode else tick + self._jitter(j.size)
        late = np.zeros(j.size, dtype=bool)
        if self.late_rng is not None:
            u = self.late_rng.random((j.size, 2))
            late = u[:, 0] < self.late_prob
            t = t + np.where(late, u[:, 1] * self.late_max, 0.0)
        if not self.tick_mode:
            return Reads(t, t, late, np.zeros(j.size, dtype=bool))
        clipped = t > tick
        return Reads(tick, np.minimum(t, tick), late, clipped)

    def times(self, j0: int, j1: int) -> np.ndarray:
        """Read instants (s) of ticks j in [max(j0, 1), j1) (see :meth:`read`)."""
        return self.read(j0, j1).t_read


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
