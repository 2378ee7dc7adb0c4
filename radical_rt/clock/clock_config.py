"""The SIRU clock's settings (:class:`ClockConfig`, SI units): the time tag's sequence, the
estimator's tuning, the repair and the anomaly checks, their validation, and their packing into the
clock kernel's parameter block (layout :mod:`radical_rt.clock.clock_layout`). The clock itself is
:class:`radical_rt.clock.siru_clock.SiruClock`; the method: docs/clock.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radical_rt.clock import clock_layout as L


@dataclass
class ClockConfig:
    """SIRU clock settings (SI units).

    Sequence: ``period_s``, ``ticks_per_sample`` and ``wrap`` describe the time tag (CONTRACT
    §1.5). Repair: at most ``max_bridge`` consecutive missing samples are bridged (interpolated
    increments, variance from ``bridge_accel_sigma_rad_s2``); longer runs are gaps. Coarse
    timing: ``jitter_margin_s`` is the tolerance of every polygon constraint (wider than the read
    jitter and offset of cycle-tagged reads), the polygon grows by ``phase_wander_s_per_s`` and
    ``freq_wander_per_s`` to follow drift, and the prior frequency offset range is
    ``freq_offset_ppm ± freq_offset_max_ppm``. Fine timing (``line_*``, ``spate_*``): the Kalman
    line on the sawtooth crossings, whose precision is jitter-limited (docs/clock.md).
    """

    period_s: float = 0.01
    ticks_per_sample: int = 10000
    wrap: int = 2**32
    mode: str = "reconstruct"  # or "naive"
    # --- estimator tuning
    jitter_margin_s: float = 1e-3  # polygon margin; grows (up to jitter_margin_max_s) if violated
    jitter_margin_max_s: float = 1e-3
    freq_offset_ppm: float = 0.0  # prior centre of the SIRU frequency offset
    freq_offset_max_ppm: float = 300.0  # prior half-width
    phase_wander_s_per_s: float = 1e-9  # phase drift bound (polygon inflation)
    freq_wander_per_s: float = 1e-10  # frequency drift bound [1/s] (1e-10/s = 0.36 ppm/hour)
    inflate_interval_s: float = 1.0
    reset_freq_margin_ppm: float = 0.5  # reset(): widen the kept frequency range by this
    slope_scale_samples: float = 1000.0  # N_s: polygon slope unit, s per N_s samples
    lock_sigma_s: float = 100e-6  # `locked` when the tag-error sigma is below this
    # --- fine line (Kalman filter on the sawtooth crossings, radical_rt.clock.clock_line)
    line_phase_rw_s_sqrt_s: float = 1e-8  # phase random walk of the line [s/√s]
    line_freq_rw_per_sqrt_s: float = 3e-10  # frequency random walk [1/√s] (0.02 ppm per hour)
    line_floor_s: float = 1e-6  # floor of the line's 1σ (the SIRU's own sample jitter) [s]
    line_gate_sigma: float = 6.0  # a crossing farther than this from the line: loss of lock
    spate_min_reads: int = 100  # a spate ends after max(this, its length) reads on one level
    spate_max_reads: int = 200_000  # a spate that does not settle within this is abandoned
    # --- repair
    max_bridge: int = 3
    bridge_accel_sigma_rad_s2: float = 1e-3  # angular-acceleration sigma for bridged variance
    # --- sequence and anomaly checks
    bus_period_s: float = 0.01
    check_bus_ticks: bool = True  # reads must fall on the bus's read ticks (within read_tol_s)
    read_tol_s: float = 2.5e-3  # a quarter of a bus period: late reads (read-instant tags) stay on grid
    time_tol_s: float = 2e-3  # tt-vs-bus-time consistency tolerance beyond one period
    max_tt_jump_samples: int = 400000  # a tt step beyond this is not a run of misses
    reset_window_ticks: int = 100_000_000  # a tt restart below this is a counter reset
    gross_violation_s: float = 1e-3  # a rejected read beyond this raises CLOCK_ANOMALY
    relock_after_reads: int = 50  # consecutive rejected reads before re-acquiring the phase
    anomaly_hold_s: float = 1.0  # CLOCK_ANOMALY stays raised this long after an event

    def validate(self) -> None:
        """Raise ValueError on an inconsistent configuration."""
        if self.mode not in ("reconstruct", "naive"):
            raise ValueError(f"mode must be 'reconstruct' or 'naive', not {self.mode!r}")
        for name in ("period_s", "ticks_per_sample", "wrap", "jitter_margin_s", "bus_period_s",
                     "slope_scale_samples", "inflate_interval_s", "freq_offset_max_ppm"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0")
        if self.max_bridge < 0 or self.relock_after_reads < 1:
            raise ValueError("max_bridge must be >= 0 and relock_after_reads >= 1")
        for name in ("line_floor_s", "line_gate_sigma", "spate_min_reads", "spate_max_reads"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0")
        for name in ("line_phase_rw_s_sqrt_s", "line_freq_rw_per_sqrt_s"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0")

    def params(self) -> np.ndarray:
        """The kernel's parameter block (``F[:NPRM]``)."""
        ns = float(self.slope_scale_samples)
        y = self.period_s * ns * 1e-6
        return L.PRM.pack({
            "t": self.period_s,
            "ticks": self.ticks_per_sample,
            "wrap": self.wrap,
            "naive": 1.0 if self.mode == "naive" else 0.0,
            "delta": self.jitter_margin_s,
            "ns": ns,
            "read_tol": self.read_tol_s,
            "bus_t": self.bus_period_s,
            "check_ticks": 1.0 if self.check_bus_ticks else 0.0,
            "max_bridge": self.max_bridge,
            "sig_alpha": self.bridge_accel_sigma_rad_s2,
            "hold": self.anomaly_hold_s,
            "gross": self.gross_violation_s,
            "relock": self.relock_after_reads,
            "reset_ticks": self.reset_window_ticks,
            "infl_dt": self.inflate_interval_s,
            "phase_wander": self.phase_wander_s_per_s,
            "freq_wander": self.freq_wander_per_s,
            "y_lo": (self.freq_offset_ppm - self.freq_offset_max_ppm) * y,
            "y_hi": (self.freq_offset_ppm + self.freq_offset_max_ppm) * y,
            "max_jump": self.max_tt_jump_samples,
            "lock_sigma": self.lock_sigma_s,
            "time_tol": self.time_tol_s,
            "delta_max": max(self.jitter_margin_max_s, self.jitter_margin_s),
            "line_qx": self.line_phase_rw_s_sqrt_s ** 2,
            "line_qy": (self.line_freq_rw_per_sqrt_s * self.period_s * ns) ** 2,
            "spate_wmin": self.spate_min_reads,
            "line_floor": self.line_floor_s,
            "line_gate": self.line_gate_sigma,
            "spate_max": self.spate_max_reads,
        })
