"""An independent generator of SIRU bus reads for the clock tests (the CONTRACT §1.5 mechanism,
neither replayer.synth's code nor the engine's): SIRU sample k at t0 + k T (1 + ε) + jitter,
counter (tt0 + 10000 k) mod 2**32, bus reads at the bus's 100 Hz ticks (with jitter) that get the
latest sample taken at or before them; helpers that run a clock over the reads and compare."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radical_rt.clock.siru_clock import GyroBatch, SiruClock

T = 0.01
WRAP = 2**32
N_GYRO = 4


@dataclass
class Reads:
    """Bus reads (t_bus, tt, dtheta, status) and their truth (sample index per read, sample
    times and increments per sample)."""

    t_bus: np.ndarray
    tt: np.ndarray
    dtheta: np.ndarray
    status: np.ndarray
    k: np.ndarray  # true sample index of each read
    t_true: np.ndarray  # true time of each sample
    dth_true: np.ndarray  # increments of each sample

    @property
    def repeated(self) -> int:
        return int(np.sum(np.diff(self.k) == 0))

    @property
    def missing(self) -> int:
        return int(np.sum(np.maximum(np.diff(self.k) - 1, 0)))

    @property
    def distinct(self) -> int:
        return int(np.sum(np.diff(self.k) > 0) + 1)

    def cut(self, mask: np.ndarray) -> Reads:
        return Reads(self.t_bus[mask], self.tt[mask], self.dtheta[mask], self.status[mask],
                     self.k[mask], self.t_true, self.dth_true)


def make_reads(n_reads: int = 30000, eps_ppm: float = 40.0, phase: float = 0.0043,
               sample_jitter: float = 1e-6, read_jitter: float = 20e-6, tt0: int = 0,
               reset_at: float | None = None, t_start: float = 1000.0, seed: int = 0) -> Reads:
    """Reads of the SIRU over ``n_reads`` bus ticks (see the module docstring). ``reset_at``:
    bus time (s after t_start) at which the counter restarts at 0 (for the first later sample)."""
    rng = np.random.default_rng(seed)
    n_s = n_reads + 10
    k = np.arange(n_s)
    t = (t_start + phase + k * T * (1 + eps_ppm * 1e-6)
         + np.clip(rng.standard_normal(n_s), -4, 4) * sample_jitter)
    tau = (t_start + T * np.arange(1, n_reads + 1)
           + np.clip(rng.standard_normal(n_reads), -4, 4) * read_jitter)
    kr = np.searchsorted(t, tau, side="right") - 1
    keep = kr >= 0
    tau, kr = tau[keep], kr[keep]
    tt_s = (tt0 + 10000 * k) % WRAP
    if reset_at is not None:
        k_r = int(np.searchsorted(t, t_start + reset_at))
        tt_s[k_r:] = 10000 * (k[k_r:] - k_r)
    dth = rng.normal(0.0, 1e-5, (n_s, N_GYRO))
    return Reads(tau, tt_s[kr], dth[kr], np.zeros(kr.size, np.int64), kr, t, dth)


def run(clock: SiruClock, r: Reads, splits=None) -> GyroBatch:
    """Push the reads (in one call, or split at the given indices), flush, concatenate."""
    edges = [0, *(splits or []), len(r.t_bus)]
    out = [clock.push(r.t_bus[a:b], r.tt[a:b], r.dtheta[a:b], r.status[a:b])
           for a, b in zip(edges[:-1], edges[1:], strict=True)]
    out.append(clock.flush())
    return GyroBatch(*(np.concatenate([getattr(b, f) for b in out]) for f in GyroBatch._fields))


def run_tt(clock: SiruClock, r: Reads, chunk: int = 10) -> tuple[GyroBatch, np.ndarray, list]:
    """Push in messages of ``chunk`` reads; also return the time tag of each output sample and
    the anomaly flag after each message."""
    out, tts, flags = [], [], []
    for a in range(0, len(r.t_bus), chunk):
        out.append(clock.push(r.t_bus[a:a + chunk], r.tt[a:a + chunk], r.dtheta[a:a + chunk],
                              r.status[a:a + chunk]))
        tts.append(clock.last_tt)
        flags.append((float(r.t_bus[min(a + chunk, len(r.t_bus)) - 1]), clock.anomaly))
    out.append(clock.flush())
    tts.append(clock.last_tt)
    b = GyroBatch(*(np.concatenate([getattr(x, f) for x in out]) for f in GyroBatch._fields))
    return b, np.concatenate(tts), flags


def time_errors(b: GyroBatch, r: Reads) -> np.ndarray:
    """Reconstructed minus true time of every non-bridged output, matching samples in order."""
    k_first = r.k[np.r_[True, np.diff(r.k) > 0]]
    t = b.t[~b.bridged]
    assert t.size == k_first.size
    return t - r.t_true[k_first]


def assert_counts(c: dict, r: Reads) -> None:
    assert c["repeated"] == r.repeated
    assert c["missing"] == r.missing
    assert c["samples"] == r.distinct
