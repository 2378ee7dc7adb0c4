"""Detection half of the FDI (docs/fdi.md §2): thresholds from one design false-alarm rate, and the
parity tests on the calibrated innovations ν of consecutive parity sums.

* an instantaneous χ²(1) test, a persistence test (``PERSIST_M`` consecutive χ² exceedances) and
  two one-sided CUSUMs (reference value k = ``CUSUM_SHIFT``/2) for small or slowly growing faults;
* a convergence-aware guard: while the calibration part of σ² dominates the noise (ρ = σ²/R above
  the guard ratio), the sequential tests are held and the instantaneous threshold is raised.

Used by :class:`radical_rt.fdi.monitor.FaultMonitor`; the bank's consistency test uses :func:`chi2_isf`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from statistics import NormalDist
from typing import Any

# Fixed design constants (tuning that is not in the parameter table; docs/fdi.md §5).
PERSIST_M = 3  # consecutive χ² exceedances of the persistence test
CUSUM_SHIFT = 1.0  # design mean shift of the CUSUM, in units of σ (reference value k = shift/2)

_NORMAL = NormalDist()


def chi2_1_isf(a: float) -> float:
    """T with P(χ²₁ > T) = a (exact: χ²₁ = Z², so √T is the two-sided normal quantile)."""
    return _NORMAL.inv_cdf(0.5 * a) ** 2


@functools.lru_cache(maxsize=64)
def _normal_isf(p: float) -> float:
    """z with P(N(0, 1) > z) = p (cached: the bank asks for one p thousands of times)."""
    return -_NORMAL.inv_cdf(p)


def chi2_isf(p: float, dof: int) -> float:
    """T with P(χ²_dof > T) ≈ p (Wilson–Hilferty; at p = 1e-4 it is 3.5 % high for dof = 3 and
    within 0.4 % for dof ≥ 30; the bank uses dof = 3 × tracker samples)."""
    z = _normal_isf(p)
    c = 2.0 / (9.0 * dof)
    return dof * (1.0 - c + z * math.sqrt(c)) ** 3


def cusum_arl0(h: float, k: float) -> float:
    """Siegmund's approximation of the average run length (in samples) of the one-sided CUSUM
    S ← max(0, S + ν − k), alarm S ≥ h, for ν ~ N(0, 1):  [e^{2kb} − 2kb − 1]/(2k²), b = h + 1.166."""
    b = h + 1.166
    x = 2.0 * k * b
    return (math.expm1(x) - x) / (2.0 * k * k)


def cusum_threshold(arl0: float, k: float) -> float:
    """Smallest h ≥ 0 with :func:`cusum_arl0` (h, k) ≥ arl0 (bisection)."""
    lo, hi = 0.0, 1.0
    while cusum_arl0(hi, k) < arl0:
        hi *= 2.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        if cusum_arl0(mid, k) < arl0:
            lo = mid
        else:
            hi = mid
    return hi


@dataclass(frozen=True)
class Thresholds:
    """Detection thresholds derived from a false-alarm rate (docs/fdi.md §2)."""

    rate_per_hr: float  # design false-alarm rate of the whole detector [1/h]
    sums_per_hr: float  # parity sums per hour
    t_inst: float  # ν² above this: instantaneous alarm
    t_persist: float  # ν² above this PERSIST_M times in a row: persistence alarm
    cusum_k: float  # CUSUM reference value [σ]
    cusum_h: float  # CUSUM threshold [σ]


def thresholds(rate_per_hr: float, sums_per_hr: float) -> Thresholds:
    """Split the false-alarm budget equally over the instantaneous test, the persistence test and
    the two one-sided CUSUMs, and invert each test's false-alarm probability:

    * instantaneous: n_h·P(χ²₁ > T) = λ/3;
    * persistence: n_h·α^m = λ/3 with α = P(χ²₁ > T_p) (sums nearly independent);
    * CUSUM: each side's ARL0 (Siegmund) = 6·n_h/λ sums.
    """
    lam = max(float(rate_per_hr), 1e-300)
    a_inst = min(lam / 3.0 / sums_per_hr, 0.5)
    a_pers = min((lam / 3.0 / sums_per_hr) ** (1.0 / PERSIST_M), 0.5)
    k = 0.5 * CUSUM_SHIFT
    return Thresholds(lam, sums_per_hr, chi2_1_isf(a_inst), chi2_1_isf(a_pers),
                      k, cusum_threshold(6.0 * sums_per_hr / lam, k))


# ----------------------------------------------------------------------------- detection
class ParityDetector:
    """The three parity tests on the normalized innovations ν of consecutive sums.

    :meth:`update` returns ``(test, t_onset)`` when a test fires (``"instant"``, ``"persistence"``
    or ``"cusum"``; t_onset = start of the first sum of the evidence), else None.
    """

    def __init__(self, th: Thresholds, guard_ratio: float) -> None:
        self.th, self.guard_ratio = th, guard_ratio
        self.reset()

    def reset(self) -> None:
        self.s_pos = self.s_neg = 0.0
        self.t_pos = self.t_neg = math.nan
        self.run, self.t_run = 0, math.nan
        self.quiet = 0
        self.guarded = False

    STATE = ("s_pos", "s_neg", "t_pos", "t_neg", "run", "t_run", "quiet", "guarded")

    def get_state(self) -> dict[str, Any]:
        """The running statistics (checkpoints; NaN times as None)."""
        return {k: (None if isinstance(v, float) and math.isnan(v) else v)
                for k in self.STATE for v in (getattr(self, k),)}

    def set_state(self, st: dict[str, Any]) -> None:
        """Put :meth:`get_state` values back (validated by the caller)."""
        for k in self.STATE:
            v = st[k]
            setattr(self, k, math.nan if v is None else v)

    def update(self, nu: float, rho: float, t0: float) -> tuple[str, float] | None:
        th = self.th
        nu2 = nu * nu
        self.guarded = rho > self.guard_ratio
        if self.guarded:
            # Calibration-dominated innovation variance: the sequential tests are held, and only
            # evidence that is overwhelming against the calibration part too raises an alarm.
            self.s_pos = self.s_neg = 0.0
            self.run = 0
            self.quiet = 0
            return ("instant", t0) if nu2 > th.t_inst * rho / self.guard_ratio else None
        hit = None
        if nu2 > th.t_inst:
            hit = ("instant", t0)
        if nu2 > th.t_persist:
            if self.run == 0:
                self.t_run = t0
            self.run += 1
        else:
            self.run = 0
        if hit is None and self.run >= PERSIST_M:
            hit = ("persistence", self.t_run)
        s = max(0.0, self.s_pos + nu - th.cusum_k)
        if self.s_pos == 0.0 and s > 0.0:
            self.t_pos = t0
        self.s_pos = s
        s = max(0.0, self.s_neg - nu - th.cusum_k)
        if self.s_neg == 0.0 and s > 0.0:
            self.t_neg = t0
        self.s_neg = s
        if hit is None and self.s_pos >= th.cusum_h:
            hit = ("cusum", self.t_pos)
        if hit is None and self.s_neg >= th.cusum_h:
            hit = ("cusum", self.t_neg)
        calm = nu2 <= th.t_persist and max(self.s_pos, self.s_neg) < 0.5 * th.cusum_h
        self.quiet = self.quiet + 1 if calm else 0
        return hit


__all__ = ["CUSUM_SHIFT", "PERSIST_M", "ParityDetector", "Thresholds", "chi2_1_isf", "chi2_isf",
           "cusum_arl0", "cusum_threshold", "thresholds"]
