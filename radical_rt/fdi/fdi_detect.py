"""Detection half of the FDI (docs/fdi.md §2): thresholds from one design false-alarm rate, and the
parity tests on the calibrated innovations ν of consecutive parity sums.

* an instantaneous χ²(1) test, a persistence test (``PERSIST_M`` consecutive χ² exceedances) and
  two one-sided CUSUMs (reference value k = ``CUSUM_SHIFT``/2) for small or slowly growing faults;
* a convergence-aware guard: while the calibration part of σ² dominates the noise (ρ = σ²/R above
  the guard ratio), the sequential tests are held and the instantaneous threshold is raised.

The tests are one compiled step, :func:`detector_step`, on a flat state array (layout :data:`DET`)
and configuration (:data:`DTH`): :class:`ParityDetector` runs it at the FDI's window hook, and
the engine's compiled loop runs it itself on the sums it may take without that hook
(:mod:`radical_rt.fdi.fdi_quiet`). Used by :class:`radical_rt.fdi.monitor.FaultMonitor`; the
bank's consistency test uses :func:`chi2_isf`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from statistics import NormalDist
from typing import Any

import numpy as np

from radical_rt._jit import kernel
from radical_rt.contract.layout import Fields

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
#: the detector's running statistics (float64): CUSUM sums [σ] and their onsets [s], the
#: persistence run (count) and its onset [s], calm sums in a row (count), 1 while guarded
DET = Fields("fdi.det", "float64")
D_S_POS = DET.add("s_pos", doc="upper CUSUM sum [sigma]")
D_S_NEG = DET.add("s_neg", doc="lower CUSUM sum [sigma]")
D_T_POS = DET.add("t_pos", unit="s", doc="onset of the upper sum (NaN: none)")
D_T_NEG = DET.add("t_neg", unit="s", doc="onset of the lower sum (NaN: none)")
D_RUN = DET.add("run", doc="consecutive persistence exceedances")
D_T_RUN = DET.add("t_run", unit="s", doc="onset of the run (NaN: none)")
D_QUIET = DET.add("quiet", doc="calm sums in a row")
D_GUARDED = DET.add("guarded", doc="1: the last sum was guarded")
DET.freeze()
#: the detector's configuration (float64): Thresholds and the guard ratio
DTH = Fields("fdi.det_th", "float64")
H_INST = DTH.add("t_inst", doc="instantaneous threshold on nu^2")
H_PERSIST = DTH.add("t_persist", doc="persistence threshold on nu^2")
H_K = DTH.add("cusum_k", doc="CUSUM reference value [sigma]")
H_H = DTH.add("cusum_h", doc="CUSUM threshold [sigma]")
H_GUARD = DTH.add("guard_ratio", doc="rho above this: guarded")
DTH.freeze()

#: detector_step's verdicts (0: none) and their names
HIT_NONE, HIT_INSTANT, HIT_PERSISTENCE, HIT_CUSUM = 0, 1, 2, 3
HIT_NAMES = (None, "instant", "persistence", "cusum")


@kernel
def detector_step(s, th, nu, rho, t0):
    """One parity sum through the three tests: s (DET.end,) the running statistics (D_*, in
    place), th (DTH.end,) the configuration (H_*), nu the normalized innovation, rho = σ²/R,
    t0 [s] the sum's first sample. Returns (HIT_*, onset [s]: the start of the first sum of the
    evidence; NaN with HIT_NONE)."""
    nu2 = nu * nu
    guarded = rho > th[H_GUARD]
    s[D_GUARDED] = 1.0 if guarded else 0.0
    if guarded:
        # Calibration-dominated innovation variance: the sequential tests are held, and only
        # evidence that is overwhelming against the calibration part too raises an alarm.
        s[D_S_POS] = 0.0
        s[D_S_NEG] = 0.0
        s[D_RUN] = 0.0
        s[D_QUIET] = 0.0
        if nu2 > th[H_INST] * rho / th[H_GUARD]:
            return HIT_INSTANT, t0
        return HIT_NONE, math.nan
    hit, onset = HIT_NONE, math.nan
    if nu2 > th[H_INST]:
        hit, onset = HIT_INSTANT, t0
    if nu2 > th[H_PERSIST]:
        if s[D_RUN] == 0.0:
            s[D_T_RUN] = t0
        s[D_RUN] += 1.0
    else:
        s[D_RUN] = 0.0
    if hit == HIT_NONE and s[D_RUN] >= PERSIST_M:
        hit, onset = HIT_PERSISTENCE, s[D_T_RUN]
    x = s[D_S_POS] + nu - th[H_K]
    x = x if x > 0.0 else 0.0  # (max(0, x) of either sign of zero: +0.0)
    if s[D_S_POS] == 0.0 and x > 0.0:
        s[D_T_POS] = t0
    s[D_S_POS] = x
    x = s[D_S_NEG] - nu - th[H_K]
    x = x if x > 0.0 else 0.0
    if s[D_S_NEG] == 0.0 and x > 0.0:
        s[D_T_NEG] = t0
    s[D_S_NEG] = x
    if hit == HIT_NONE and s[D_S_POS] >= th[H_H]:
        hit, onset = HIT_CUSUM, s[D_T_POS]
    if hit == HIT_NONE and s[D_S_NEG] >= th[H_H]:
        hit, onset = HIT_CUSUM, s[D_T_NEG]
    big = s[D_S_NEG] if s[D_S_NEG] > s[D_S_POS] else s[D_S_POS]  # (max(s_pos, s_neg))
    calm = nu2 <= th[H_PERSIST] and big < 0.5 * th[H_H]
    s[D_QUIET] = s[D_QUIET] + 1.0 if calm else 0.0
    return hit, onset


class ParityDetector:
    """The three parity tests on the normalized innovations ν of consecutive sums
    (:func:`detector_step`, the one implementation, also run by the engine's compiled loop).

    :meth:`update` returns ``(test, t_onset)`` when a test fires (``"instant"``, ``"persistence"``
    or ``"cusum"``; t_onset = start of the first sum of the evidence), else None. The running
    statistics live in ``state`` (DET layout; the caller's array when given: the FDI's
    radical_rt.fdi.fdi_quiet array, which the compiled loop updates in place), the configuration in
    ``config`` (DTH layout); the attributes below read and write them.
    """

    def __init__(self, th: Thresholds, guard_ratio: float, state: np.ndarray | None = None,
                 config: np.ndarray | None = None) -> None:
        self.th, self.guard_ratio = th, guard_ratio
        self.state = np.zeros(DET.end) if state is None else state
        self.config = np.zeros(DTH.end) if config is None else config
        self.config[:] = (th.t_inst, th.t_persist, th.cusum_k, th.cusum_h, guard_ratio)
        self.reset()

    def reset(self) -> None:
        self.state[:] = (0.0, 0.0, math.nan, math.nan, 0.0, math.nan, 0.0, 0.0)

    STATE = ("s_pos", "s_neg", "t_pos", "t_neg", "run", "t_run", "quiet", "guarded")

    s_pos = property(lambda self: self.state.item(D_S_POS),
                     lambda self, v: self.state.__setitem__(D_S_POS, v))
    s_neg = property(lambda self: self.state.item(D_S_NEG),
                     lambda self, v: self.state.__setitem__(D_S_NEG, v))
    t_pos = property(lambda self: self.state.item(D_T_POS),
                     lambda self, v: self.state.__setitem__(D_T_POS, v))
    t_neg = property(lambda self: self.state.item(D_T_NEG),
                     lambda self, v: self.state.__setitem__(D_T_NEG, v))
    run = property(lambda self: int(self.state.item(D_RUN)),
                   lambda self, v: self.state.__setitem__(D_RUN, v))
    t_run = property(lambda self: self.state.item(D_T_RUN),
                     lambda self, v: self.state.__setitem__(D_T_RUN, v))
    quiet = property(lambda self: int(self.state.item(D_QUIET)),
                     lambda self, v: self.state.__setitem__(D_QUIET, v))
    guarded = property(lambda self: self.state.item(D_GUARDED) != 0.0,
                       lambda self, v: self.state.__setitem__(D_GUARDED, 1.0 if v else 0.0))

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
        hit, onset = detector_step(self.state, self.config, nu, rho, t0)
        return None if hit == HIT_NONE else (HIT_NAMES[hit], onset)


__all__ = ["CUSUM_SHIFT", "DET", "DTH", "PERSIST_M", "ParityDetector", "Thresholds", "chi2_1_isf",
           "chi2_isf", "cusum_arl0", "cusum_threshold", "detector_step", "thresholds"]
