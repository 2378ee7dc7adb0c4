"""Covariance analysis of a planned maneuver: the engine's own UD filter run without data.

What it runs. The planned attitude history (a *trajectory*: any object with the two methods of
:class:`replayer.synth.maneuver.Profile`, ``truth_attitude(t) -> (q_body_from_inertial (k, 4),
omega_body (k, 3) rad/s)`` and ``rotation_increment(t1, t2) -> theta (k, 3) rad, body``) is turned
into the *noise-free* measurements a perfect sensor set would give at the linearization point
(nominal calibration, all parameters zero):

* SIRU samples every ``siru_period_s``: ``dθ_i = w_iᵀθ_k`` (θ_k the exact body rotation over the
  sample, w_i the nominal sense axes), no noise, no quantization;
* tracker samples at ``tracker_rate_hz`` with epoch ``t_bus − latency``: ``q_stj_from_inertial``
  of the exact attitude at the epoch (nominal mountings), ``n_stars`` stars (or cycling through
  ``n_stars_cycle``), valid; left out where the plan's ``tracker_visible`` says the tracker is
  blinded (Sun exclusion) and, evenly spread, the expected share of lost samples.

These are released to an unmodified :class:`radical_rt.engine.filter.Engine` exactly as
:class:`radical_rt.stream.processor.StreamProcessor` releases them (:meth:`Engine.release`: for every
tracker sample the gyro samples up to its epoch, then the sample; the compiled loop of
``radical process``). Since the measurements equal the engine's prediction, every
innovation is zero (to round-off) and the estimate stays at the linearization point: what changes
is the covariance only, propagated and updated by the engine's own models — gyro propagation
Jacobians and the ARW noise, the regressor reliability κ, parameter random walks, the tracker
noise ``(3.2″, 3.2″, 29″)·√(9/n)`` of the parameter table, the parity sums with their lag, the
residual-latency state, the time-line consider rule — i.e. a covariance analysis with the filter's
own equations. The noise enters only through the noise model of the table (``arw_deg_sqrt_hr``,
``quant_arcsec``, ``st_sigma_*``); the plan's noise-free data never pretends to be information.

The SIRU clock is not simulated: the time line's 1σ ``σ_t`` is modelled as ``sigma_unlocked_s``
before ``lock_s`` (the clock's second sawtooth wrap after a cold start, its first after a warm
start that keeps the frequency, see :func:`clock_lock_s`) and ``sigma_locked_s`` after it, read by
the engine through its hooks, :class:`PlanClock` (the consider rule of docs/engine.md §3.3).

Outputs are SI: σ of the CONTRACT parameters (npar = 5n + 3 + 1 incl. the latency state) over
time, and the final parameter covariance (contract coordinates).
"""

from __future__ import annotations

import math
import types
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from radical_rt.engine.filter import Engine

#: the clock's σ_t before lock: a tag anywhere in the 10 ms band (10 ms/√12) [s]
SIGMA_UNLOCKED_S = 2.9e-3
#: and after lock (well below the engine's timing_consider_s = 100 µs) [s]
SIGMA_LOCKED_S = 5e-6


@dataclass
class Plan:
    """A maneuver to analyse: trajectory and sensor set-up (SI, bus times).

    trajectory: see the module docstring; t0: bus time of the stream start [s]; duration_s;
    siru_period_s: gyro sample period [s]; tracker_rate_hz; latency_s: tracker latency (the
    epoch is t_bus − latency) [s]; n_stars: stars tracked (noise scales with √(9/n));
    trackers: (ST1 on, ST2 on); lock_s: time after t0 from which the SIRU time line is locked [s];
    tracker_visible: optional callable(j, epochs (k,)) → bool (k,), False where tracker j is
    blinded (Sun in its exclusion cone).
    """

    trajectory: object
    t0: float
    duration_s: float
    siru_period_s: float = 0.01
    tracker_rate_hz: float = 10.0
    latency_s: float = 0.115
    n_stars: int = 9
    trackers: tuple[bool, bool] = (True, True)
    lock_s: float = 392.0
    sigma_unlocked_s: float = SIGMA_UNLOCKED_S
    sigma_locked_s: float = SIGMA_LOCKED_S
    tracker_visible: Callable | None = None
    #: star counts cycled through sample by sample (their mean information, the stationary
    #: distribution of the simulator's star-count random walk), None: always n_stars
    n_stars_cycle: tuple[int, ...] | None = None
    #: fraction of tracker samples that arrive valid (1 − invalid − dropout probability); the
    #: others are left out evenly spread
    tracker_keep: float = 1.0


@dataclass
class History:
    """σ of the contract parameters over time: t (k,) [s after t0], sigma (k, npar) SI, and the
    final contract-parameter covariance cov (npar, npar) SI; counters of the engine."""

    t: np.ndarray
    sigma: np.ndarray
    cov: np.ndarray
    counters: dict = field(default_factory=dict)
    elapsed_s: float = 0.0


def clock_lock_s(period_s: float = 0.01, eps_ppm: float = 40.0, phase_s: float = 0.0043,
                 bus_period_s: float = 0.01, wraps: int = 2) -> float:
    """Time after the stream start [s] of the ``wraps``-th sawtooth wrap of the tag error.

    Reads at k·bus_period tag the latest sample taken at phase + m·period(1+ε); the tag error
    starts at (bus_period − phase) mod period' and falls by ε per second (SIRU slower than the
    bus), wrapping every period'/ε s (|ε| for a fast SIRU, mirrored). The clock reconstruction
    locks at the second wrap after a cold start (frequency and phase), at the first when it
    keeps the frequency across a warm start (docs/warm_vs_cold.md)."""
    eps = abs(eps_ppm) * 1e-6
    if eps == 0.0:
        return math.inf
    p = period_s * (1.0 + eps_ppm * 1e-6)
    e0 = (bus_period_s - phase_s) % p
    if eps_ppm < 0:
        e0 = p - e0
    return e0 / eps + (wraps - 1) * p / eps


def gyro_samples(plan: Plan, geo_W: np.ndarray):
    """Noise-free SIRU samples of the plan: the engine's gyro arrays (t, dt, dtheta (m, n),
    status, bridged, var_extra); dtheta_i = w_iᵀθ (nominal axes W (3, n), rad)."""
    T = plan.siru_period_s
    m = int(math.floor(plan.duration_s / T + 1e-9))
    k = np.arange(1, m + 1, dtype=float)
    t = plan.t0 + k * T
    theta = plan.trajectory.rotation_increment(t - T, t)  # (m, 3) body
    dtheta = np.ascontiguousarray(theta @ geo_W)
    n = geo_W.shape[1]
    return (t, np.full(m, T), dtheta, np.zeros(m, np.int64), np.zeros(m, np.bool_),
            np.zeros(m)), n


def tracker_events(plan: Plan, geo) -> types.SimpleNamespace:
    """Noise-free tracker samples in release order (epoch, ST1 before ST2): the row arrays of a
    :class:`radical_rt.stream.tracker_queue.TrackerQueue` (``ev_f`` (k, 5) epoch [s] and
    q_st_from_inertial, ``ev_i`` (k, 4) tracker, n_stars, valid, arrival; ``out_f``, ``out_i``
    the kernel's output rows)."""
    period = 1.0 / plan.tracker_rate_hz
    k = np.arange(1, int(math.floor(plan.duration_s * plan.tracker_rate_hz + 1e-9)) + 1)
    epochs = plan.t0 + k * period - plan.latency_s
    epochs = epochs[epochs > plan.t0]
    q_bi, _ = plan.trajectory.truth_attitude(epochs)
    r_bi = Rotation.from_quat(q_bi)
    rows_f, rows_i = [], []
    mounts = ((1, geo.R_st1_from_body), (2, geo.R_st2_from_body_nom))
    for (j, R), on in zip(mounts, plan.trackers, strict=True):
        if not on:
            continue
        q = (Rotation.from_matrix(R) * r_bi).as_quat()
        vis = np.ones(len(epochs), bool)
        if plan.tracker_visible is not None:
            vis = np.asarray(plan.tracker_visible(j, epochs), bool)
        if plan.tracker_keep < 1.0:  # evenly spread losses (offset per tracker)
            kk = np.arange(len(epochs)) + 0.5 * j
            vis &= np.floor(kk * (1.0 - plan.tracker_keep)) == np.floor((kk - 1) * (1.0 - plan.tracker_keep))
        stars = np.full(len(epochs), plan.n_stars, np.int64)
        if plan.n_stars_cycle:
            cyc = np.asarray(plan.n_stars_cycle, np.int64)
            stars = cyc[(np.arange(len(epochs)) + j) % len(cyc)]
        f = np.column_stack([epochs, q])[vis]
        i = np.zeros((len(f), 4), np.int64)
        i[:, 0], i[:, 1], i[:, 2] = j, stars[vis], 1
        rows_f.append(f)
        rows_i.append(i)
    f = np.concatenate(rows_f) if rows_f else np.zeros((0, 5))
    i = np.concatenate(rows_i) if rows_i else np.zeros((0, 4), np.int64)
    order = np.lexsort((i[:, 0], f[:, 0]))
    f, i = np.ascontiguousarray(f[order]), np.ascontiguousarray(i[order])
    i[:, 3] = np.arange(len(i))
    return types.SimpleNamespace(ev_f=f, ev_i=i, out_f=np.zeros((len(f), 7)),
                                 out_i=np.zeros((len(f), 4), np.int64))


class PlanClock:
    """The engine's hooks in a covariance analysis (radical_rt.engine.hooks): the σ of the gyro
    time line of the plan being run (:meth:`follow`), before and after the clock locks; no
    outputs."""

    def __init__(self) -> None:
        self.lock_t, self.sigma_unlocked_s, self.sigma_locked_s = math.inf, 0.0, 0.0

    def follow(self, plan: Plan) -> None:
        """Model the time line of ``plan`` from now on."""
        self.lock_t = plan.t0 + plan.lock_s
        self.sigma_unlocked_s, self.sigma_locked_s = plan.sigma_unlocked_s, plan.sigma_locked_s

    def timing_sigma(self, t: float) -> float:
        return self.sigma_locked_s if t >= self.lock_t else self.sigma_unlocked_s

    def wake(self) -> tuple[float, float]:
        return math.inf, math.inf

    def on_window(self, t: float) -> None:
        return None


def new_engine(table=None) -> Engine:
    """A cold-started engine as ``radical process`` makes it, without the FDI (no faults to find
    in noise-free data; it never changes the covariance of a healthy run), whose time line is
    the plan's (:class:`PlanClock`; :func:`run_plan` points it at each plan)."""
    return Engine(table, hooks=PlanClock(), fdi=False)


def run_plan(plan: Plan, engine: Engine, record_dt: float = 10.0, chunk_s: float = 0.5,
             progress: Callable[[float], None] | None = None) -> History:
    """Release the plan's noise-free samples to ``engine`` (cold-started or warm-started by the
    caller) in chunks of ``chunk_s`` (the time-line σ is read per release, as the stream does at
    ~10 Hz), recording σ every ``record_dt`` s; flush the parity queue at the end (as
    ``end_stream``). progress: callable(fraction) after every record. Returns a :class:`History`."""
    import time

    from radical_rt.stream.tracker_queue import EventBlock

    w0 = time.perf_counter()
    arrays, _n = gyro_samples(plan, engine.geo.W)
    tq = tracker_events(plan, engine.geo)
    if not isinstance(engine.hooks, PlanClock):
        raise TypeError("run_plan needs an engine made by new_engine (its hooks model the clock)")
    engine.hooks.follow(plan)
    t_g, epochs = arrays[0], tq.ev_f[:, 0]
    n_chunks = max(1, int(math.ceil(plan.duration_s / chunk_s)))
    every = max(1, int(round(record_dt / chunk_s)))
    ts, sig = [0.0], [engine.contract_sigma()]
    a = e = 0
    for c in range(1, n_chunks + 1):
        t_c = plan.t0 + c * chunk_s
        z = int(np.searchsorted(t_g, t_c, side="right"))
        e1 = int(np.searchsorted(epochs, t_c, side="right"))
        engine.release(arrays, a, z, EventBlock(tq, e, e1))
        a, e = z, e1
        if c % every == 0 or c == n_chunks:
            ts.append(min(c * chunk_s, plan.duration_s))
            sig.append(engine.contract_sigma())
            if progress is not None:
                progress(c / n_chunks)
    if engine.att_valid:
        engine.flush_parity()
    sig[-1] = engine.contract_sigma()
    _, cov = engine.contract_params()
    return History(np.asarray(ts), np.asarray(sig), cov, dict(engine.counters),
                   time.perf_counter() - w0)
