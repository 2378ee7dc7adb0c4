"""The RADICAL engine: cold/warm start, propagation, parity and tracker updates, editing, bumps.

The engine is driven by events in time order (see :mod:`radical_rt.stream.processor`): gyro batches
(:class:`radical_rt.clock.siru_clock.GyroBatch`, reconstructed sample times) and tracker samples at their
epoch on the gyro time line. It holds only UD factors (U, d) of the covariance; full covariance
entries are computed for outputs only. All numbers SI; see :mod:`radical_rt.contract.conventions`.

Cycle (notes §14, docs/engine.md): samples are propagated one by one; every ``prop_window``
samples, or at a tracker epoch, the time-update window closes: structured UD time update and
parameter process noise (Agee-Turner). At a tracker epoch the three tracker residual components
follow (joint χ² edit test, then scalar Bierman updates). The correction is then folded into the
attitude quaternion and the parameters. The parity (null-space) measurement is a sum over
``parity_window`` samples kept as sufficient statistics and processed ``parity_lag_s`` later,
linearized about the estimate of that time. All of it runs compiled, in one call per release
(:mod:`radical_rt.engine.loop`, steps in :mod:`radical_rt.engine.steps`); this class
configures it, runs the window hook and the commands (starts, bumps, isolation), and reports.

The gyro parameters are estimated in the internal *linear* form of :mod:`radical_rt.kernels.model` (scaled
sense axes a_i = (1+λ')w_i − du'v_i − dv'u_i, μ' = μ/(1+λ)); :meth:`EngineState.estimates` and
:meth:`EngineState.sigmas` report the CONTRACT's parameters (exact conversion, covariance mapped).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from radical_rt.contract.conventions import SIRU_PERIOD_S
from radical_rt.contract.flags import Flag
from radical_rt.contract.geometry import Geometry
from radical_rt.contract.params import ParamTable, to_si
from radical_rt.contract.state import PARAM_GROUPS, StateLayout
from radical_rt.engine.engine_state import EDITED_KEY, USED_KEY, EngineState, sigma_of
from radical_rt.engine.events import (
    EV_BEGIN_ATTITUDE_INIT,
    EV_FLUSH,
    EV_NUMERIC,
    EV_RESET_PARITY,
)
from radical_rt.engine.excitation import ExcitationMonitor
from radical_rt.engine.hooks import EngineHooks, NoHooks
from radical_rt.engine.shell import LoopShell
from radical_rt.fdi.monitor import FaultMonitor
from radical_rt.kernels import ud, ud_time
from radical_rt.kernels.model import refresh_axes
from radical_rt.kernels.parametrization import output_numbers
from radical_rt.kernels.timeupdate import ACC_NOISE_T


class Engine(LoopShell, EngineState):
    """The 3 + 5n + 3 state UD-factorized RADICAL filter (n gyros, ST1 reference, ST2 relative)."""

    def __init__(self, table: ParamTable | None = None, geometry: Geometry | None = None, *,
                 hooks: EngineHooks | None = None, fdi: bool = True,
                 excitation: bool = True) -> None:
        """table: parameter tables (defaults); geometry: the SIRU and tracker geometry (nominal);
        hooks: the process driving the engine (radical_rt.engine.hooks; NoHooks by default);
        fdi: run the parity FDI (docs/fdi.md); excitation: run the excitation monitor."""
        geometry = geometry or Geometry()
        self.hooks: EngineHooks = NoHooks()  # the given hooks once the engine is built
        super().__init__(StateLayout(geometry.n_gyro, latency=True), geometry)
        self.table = table or ParamTable(n_gyro=geometry.n_gyro)
        self._phi_col, self._lat_col = self.layout["phi2"].start, self.layout["lat"].start
        self.params_changed()
        self._pack()
        self.cold_start()
        #: the parity FDI (radical_rt.fdi.monitor; None: off) and the excitation monitor
        #: (radical_rt.engine.excitation; None: off)
        self.fdi: FaultMonitor | None = FaultMonitor() if fdi else None
        self.excitation: ExcitationMonitor | None = ExcitationMonitor(
            self.layout, triads=(geometry.W, geometry.U, geometry.V)) if excitation else None
        if hooks is not None:
            self.hooks = hooks

    # ---------------------------------------------------------------- configuration
    def params_changed(self) -> None:
        """Re-read the active parameter table (called after set/reset of parameters)."""
        self.si = to_si(self.table.active, self.n_gyro)
        new = {"q_params": np.asarray(self.si.q_params, float),
               "conv_var": np.asarray(self.si.conv_sigma, float) ** 2,
               "st_sigma": np.asarray(self.si.st_sigma, float),  # rad, tracker axes, at st_ref_stars
               "p0": np.asarray(self.si.p0_params, float)}
        for name, value in new.items():  # in place (the arrays may be packed, EngineState._pack)
            getattr(self, name)[...] = value
        self._size_parity_queue()
        self._loop_config()

    def _size_parity_queue(self) -> None:
        """Room in the parity queue for every sum of a lag (a sum every parity_window samples, at
        up to twice the nominal sample rate), the queued sums kept in order."""
        si = self.si
        need = math.ceil(si.parity_lag_s / (0.5 * si.parity_window * SIRU_PERIOD_S)) + 8
        if need > self.pq.shape[0]:
            self.set_parity_queue(self.parity_queue, rows=need)

    # ---------------------------------------------------------------- starts and bumps
    def cold_start(self) -> None:
        """Parameters zero, covariance from the table, attitude from the next valid tracker."""
        self.xp[:] = 0.0
        self.U[:, :] = np.eye(self.ns)
        self.d[:3] = 1.0
        self.d[3:] = np.asarray(self.si.p0_params)
        self.N[:, :] = self.geo.N
        self.pq_i[:] = 0  # the parity queue emptied
        self.q_dt[:] = 0.0  # no parameter noise pending for the new covariance
        self.acc_f[ACC_NOISE_T] = 0.0
        self._refresh()
        self._begin_attitude_init()
        self.flags &= ~int(Flag.NUMERIC)  # a cold start recovers from a numeric fault (latched until then)
        self.last_numeric = ""
        self.counters["cold_starts"] += 1

    def warm_start(self, bump: bool = True) -> None:
        """Reset attitude and its cross-covariance, keep the parameter UD factors; bump them."""
        self._cov_reset_attitude(np.eye(3))
        if bump:
            self.bump(dict(self.si.bump_sigma), self.si.bump_mode)
        self._begin_attitude_init()
        self.counters["warm_starts"] += 1

    def bump(self, sigma: dict[str, list[float] | tuple[float, ...]], mode: str = "add") -> None:
        """Covariance bump on parameter groups, applied to the UD factors.

        sigma: group → per-state 1σ in SI. Both modes add Δσ² to each chosen variance; "add" does it
        with Agee-Turner rank-one updates (correlations shrink), "scale" multiplies the state's σ by
        sqrt(1 + Δσ²/σ²) (P ← SPS, correlation coefficients kept).
        """
        if mode == "add":
            idx, c = [], []
            for group, values in sigma.items():
                sl = self.layout[group]
                for k, v in enumerate(values):
                    idx.append(sl.start + k)
                    c.append(float(v) ** 2)
            self._cov_add_diagonal(np.asarray(idx, np.int64), np.asarray(c))
        else:  # same diagonal increase, applied as σ scaling so correlations are kept
            var = self.variances()
            s = np.ones(self.ns)
            for group, values in sigma.items():
                sl = self.layout[group]
                s[sl] = np.sqrt(1.0 + np.asarray(values, float) ** 2 / var[sl])
            self._cov_scale(s)
        self.counters["bumps"] += 1

    # ---------------------------------------------------------------- covariance primitives
    # The covariance operations of the commands (UD factors here; the dense oracle of
    # tests/oracles/dense_engine.py overrides them with its P).
    def _cov_reset_attitude(self, P0) -> None:
        """Attitude covariance ← P0 (3, 3), attitude cross-covariances ← 0, the rest kept."""
        self._check(ud_time.reset_leading_block(self.U, self.d, 3, P0, self.ws.struct))

    def _cov_add_diagonal(self, idx, c) -> None:
        """P[idx_k, idx_k] += c_k (process noise, additive bump)."""
        self._check(ud_time.add_diagonal_noise(self.U, self.d, idx, c, self.ws.a))

    def _cov_scale(self, s) -> None:
        """P ← diag(s) P diag(s)."""
        self._check(ud_time.scale_states(self.U, self.d, s))

    def _covariance(self) -> np.ndarray:
        """P (ns, ns) from the UD factors (outputs and the excitation monitor only)."""
        P = np.empty((self.ns, self.ns))
        ud.ud_to_cov(self.U, self.d, P)
        return P

    def _begin_attitude_init(self) -> None:
        """The attitude is lost: wait for the next valid tracker (steps.begin_attitude_init)."""
        self._event(EV_BEGIN_ATTITUDE_INIT)

    # ---------------------------------------------------------------- parity queue
    @property
    def parity_queue(self) -> list[tuple[float, np.ndarray, np.ndarray, float]]:
        """The closed parity sums waiting for their lag, oldest first: (t [s], par_y (2, n),
        par_t (2, n), noise [rad²]) (copies; checkpoints)."""
        n, (head, count), K = self.n_gyro, self.pq_i.tolist(), self.pq.shape[0]
        out = []
        for r in range(count):
            row = self.pq[(head + r) % K]
            out.append((float(row[0]), row[2:2 + 2 * n].reshape(2, n).copy(),
                        row[2 + 2 * n:2 + 4 * n].reshape(2, n).copy(), float(row[1])))
        return out

    def set_parity_queue(self, items, rows: int = 0) -> None:
        """Replace the queue by ``items`` (as :attr:`parity_queue` returns them); the ring gets at
        least ``rows`` rows (repacking the state when it grows)."""
        items = list(items)
        rows = max(rows, len(items) + 8 if len(items) > self.pq.shape[0] else 0)
        if rows > self.pq.shape[0]:
            self.pq, self.pq_i = np.zeros((rows, self.pq.shape[1])), np.zeros(2, np.int64)
            if hasattr(self, "_lay"):
                self._pack()
        n = self.n_gyro
        self.pq_i[:] = (0, len(items))
        for r, (t, y, tt, noise) in enumerate(items):
            self.pq[r, :2] = (t, noise)
            self.pq[r, 2:2 + 2 * n] = np.asarray(y, float).ravel()
            self.pq[r, 2 + 2 * n:2 + 4 * n] = np.asarray(tt, float).ravel()

    def flush_parity(self) -> None:
        """End of a stream: the open parity sum queued, the sums still waiting for their lag
        updated, the correction folded (its FDI statistic goes to the FDI at once)."""
        self._event(EV_FLUSH)
        pending, self._sum_pending = self._sum_pending, None
        if pending is not None and self.fdi is not None:
            self.fdi.on_parity_sum(self, pending)

    # ---------------------------------------------------------------- hooks and bookkeeping
    def timing_sigma(self) -> float:
        """1σ [s] of the gyro time line at the latest sample (the hooks': the SIRU clock
        reconstruction), used to add (ω̂·σ_t)² along the rate to the tracker noise; 0 when the
        hooks give no finite positive value."""
        sig = float(self.hooks.timing_sigma(self.t))
        return sig if math.isfinite(sig) and sig > 0.0 else 0.0

    #: whether the time line was locked (σ_t ≤ timing_consider_s: the updates calibrate) during
    #: the Python oracle's release (tests/oracles; the compiled calls test it themselves)
    locked = False

    fdi = None  # (class defaults for the start-up, before __init__ sets them)
    excitation = None

    def _update_done(self, kind: str, innov, sig, nis: float, edited: bool) -> bool:
        """Diagnostics and counters of one tracker update (the Python oracle's, tests/oracles)."""
        self.diag_last[kind] = (innov, sig, nis)
        if edited:
            self.counters[EDITED_KEY[kind]] += 1
        else:
            self.counters[USED_KEY[kind]] += 1
            self.nis_sum[kind] += nis
            if self.locked:
                rec = self.nis_locked[kind]
                rec[0] += 1
                rec[1] += nis
        return not edited

    def state_restored(self) -> None:
        """After :meth:`set_state`: rebuild what derives from xp (scaled axes, (AAᵀ)⁻¹, pseudo-
        inverse), then put the saved parity basis N back (a rebuild re-orthogonalizes N against
        itself, which would change its last bits and break bit-identical resumes)."""
        n_saved = self.N.copy()
        self._refresh()
        self.N[...] = n_saved
        self._load_bookkeeping()  # the restored epochs and NIS sums, for the compiled calls

    def _refresh(self) -> None:
        status = refresh_axes(self.xp, self.geo.W, self.geo.U, self.geo.V, self.N.copy(), self.A,
                              self.Minv, self.Gp, self.N)
        if status != 0:
            self._numeric("sense-axis geometry singular")

    def apply_isolation(self, gyro: int, state) -> None:
        """Apply the FDI's isolation of ``gyro`` (radical_rt.fdi.monitor): exclude it; with a
        :class:`radical_rt.fdi.monitor_isolation.Reconfiguration` ``state``, take its U, d, xp, q, omega and add
        the parameter process noise over its dt_noise; with None keep the covariance and restart
        the attitude from the trackers (warm start). Then the window's correction and parity sums
        are void and the geometry is rebuilt over the remaining gyros."""
        self.excluded[gyro] = True
        if state is not None:
            self.U[:, :] = state.U
            self.d[:] = state.d
            self.xp[:] = state.xp
            self.q[:] = state.q
            self.omega[:] = state.omega
            self._check(ud_time.add_diagonal_noise(self.U, self.d, self.param_idx,
                                              self.q_params * state.dt_noise, self.ws.a))
        else:
            self.warm_start(bump=False)
        self.dx[:] = 0.0
        self.pq_i[:] = 0  # the parity queue emptied
        self._event(EV_RESET_PARITY)
        self._refresh()

    def latency_residual(self) -> float:
        """Residual tracker latency estimate τ̂ [s] (true − configured)."""
        return float(self.xp[self._lat_col - 3])

    def latency_estimate(self) -> dict[str, float]:
        """Tracker latency: configured, residual τ̂ and total estimate, with the 1σ of τ [s]."""
        ud.variances(self.U, self.d, self.ws.var)
        return self._latency_map(self.ws.var[self._lat_col].item())

    def _latency_map(self, var_tau: float) -> dict[str, float]:
        """:meth:`latency_estimate`'s map, with var_tau [s²] the variance of τ."""
        tau = self.latency_residual()
        configured = float(self.si.latency_st_s)
        return {"configured_s": configured, "residual_s": tau, "estimate_s": configured + tau,
                "sigma_s": math.sqrt(max(var_tau, 0.0))}

    def output_numbers(self) -> dict[str, Any]:
        """The telemetry fields ``est``, ``sigma``, ``att_sigma`` and ``latency`` (the maps of
        :meth:`estimates`, :meth:`sigmas`, :meth:`att_sigma`, :meth:`latency_estimate`, the same
        numbers bit for bit) from one compiled call (:func:`radical_rt.kernels.parametrization.
        output_numbers`): a packet hook reads them together."""
        npar = self.xp.shape[0]
        buf = self._numbers
        if buf is None or buf.shape[0] != 2 * npar:
            buf = self._numbers = np.empty(2 * npar)
        output_numbers(self.xp, self.n_gyro, self.U, self.d, self._jacobian_work(), buf[:npar],
                       buf[npar:], self.ws.var)
        var = self.ws.var.tolist()
        return {"est": self._by_group(buf[:npar]), "sigma": self._by_group(buf[npar:]),
                "att_sigma": [sigma_of(x) for x in var[:3]],
                "latency": self._latency_map(var[self._lat_col])}

    _numbers: np.ndarray | None = None  # est and sigma of output_numbers (2 npar,)

    # ---------------------------------------------------------------- health
    def _check(self, status: int) -> None:
        if status != 0:
            self._numeric(f"UD kernel status {status}")

    def _numeric(self, why: str) -> None:
        """Numerical-integrity failure found by Python (a command's kernel status): flag it and
        recover as the kernel does (steps.numeric_fault)."""
        self._event(EV_NUMERIC, -2)
        self.last_numeric = why

    def update_mode(self, t: float) -> None:
        """Stale-tracker flags, the convergence test and the mode after a close at event time t
        [s] (steps.window_state, the rule the compiled loop tests with)."""
        self._window_state(t)

    def on_window(self, t: float) -> None:
        """The window hook (after a close where the compiled loop stops for it; t the event time
        [s]): a parity sum queued since the last hook goes to the FDI's detector and, every 10 s,
        the excitation monitor looks at the covariance; then the FDI's bookkeeping and
        decisions, the mode and flags, and the hooks' window hook (the stream's outputs)."""
        pending, self._sum_pending = self._sum_pending, None
        if pending is not None:
            if self.fdi is not None:
                self.fdi.on_parity_sum(self, pending)
            ex = self.excitation
            if ex is not None and ex.due(self.t):
                self.flags = ex.update(self.t, self._covariance(), self.q, self.conv_var,
                                       self.flags)
        if self.fdi is not None:
            self.fdi.on_window(self, t)
        self.update_mode(t)
        self.hooks.on_window(t)


__all__ = ["Engine", "PARAM_GROUPS"]
