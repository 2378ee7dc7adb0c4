"""The RADICAL engine: cold/warm start, propagation, parity and tracker updates, editing, bumps.

The engine is driven by events in time order (see :mod:`radical_rt.stream.processor`): gyro batches
(:class:`radical_rt.clock.siru_clock.GyroBatch`, reconstructed sample times) and tracker samples at their
epoch on the gyro time line. It holds only UD factors (U, d) of the covariance; full covariance
entries are computed for outputs only. All numbers SI; see :mod:`radical_rt.contract.conventions`.

Cycle (notes §14, docs/engine.md): samples are propagated one by one
(:func:`propagate.propagate_window`); every ``prop_window`` samples, or at a tracker epoch, the
time-update window closes: structured UD time update and parameter process noise (Agee-Turner). At
a tracker epoch the three tracker residual components follow (joint χ² edit test, then scalar
Bierman updates). The correction is then folded into the attitude quaternion and the parameters.
The parity (null-space) measurement is a sum over ``parity_window`` samples kept as sufficient
statistics and processed ``parity_lag_s`` later, linearized about the estimate of that time.

The gyro parameters are estimated in the internal *linear* form of :mod:`radical_rt.kernels.model` (scaled
sense axes a_i = (1+λ')w_i − du'v_i − dv'u_i, μ' = μ/(1+λ)); :meth:`EngineState.estimates` and
:meth:`EngineState.sigmas` report the CONTRACT's parameters (exact conversion, covariance mapped).
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt.contract.flags import Flag
from radical_rt.contract.geometry import Geometry
from radical_rt.contract.params import ParamTable, to_si
from radical_rt.contract.state import PARAM_GROUPS, StateLayout
from radical_rt.engine.engine_state import EngineState, param_slice
from radical_rt.engine.excitation import ExcitationMonitor
from radical_rt.engine.fastpath_glue import ST_EDITED_BIT, ST_KIND, FastRelease
from radical_rt.fdi.monitor import FaultMonitor
from radical_rt.kernels import ud
from radical_rt.kernels.model import (
    fold_correction,
    parity_from_stats,
    quat_from_tracker,
    refresh_axes,
    tracker_rows,
)
from radical_rt.kernels.propagate import PROP_MASKED, PROP_UNDETERMINED, propagate_window
from radical_rt.kernels.timeupdate import ACC_NOISE_T, close_time_window, regressor_reliability
from radical_rt.kernels.updates import (
    gated_update,
    gated_update_consider,
    timing_noise,
    unwhiten_diagnostics,
)


class Engine(FastRelease, EngineState):
    """The 3 + 5n + 3 state UD-factorized RADICAL filter (n gyros, ST1 reference, ST2 relative)."""

    def __init__(self, table: ParamTable | None = None, geometry: Geometry | None = None) -> None:
        geometry = geometry or Geometry()
        super().__init__(StateLayout(geometry.n_gyro, latency=True), geometry)
        self.table = table or ParamTable(n_gyro=geometry.n_gyro)
        self._phi_p = param_slice(self.layout, "phi2")  # φ2 inside xp
        self._phi_col, self._lat_col = self.layout["phi2"].start, self.layout["lat"].start
        self._rate2 = 0.0  # |ω̂|² at the last tracker update [rad²/s²]
        self._views: dict[int, tuple[np.ndarray, ...]] = {}
        self.params_changed()
        self.cold_start()
        self._pack()
        self.fdi = FaultMonitor()  # parity FDI (docs/fdi.md); None disables the hooks
        self.excitation = ExcitationMonitor(  # radical_rt.engine.excitation; None: off
            self.layout, triads=(geometry.W, geometry.U, geometry.V))

    # ---------------------------------------------------------------- configuration
    def params_changed(self) -> None:
        """Re-read the active parameter table (called after set/reset of parameters)."""
        self.si = to_si(self.table.active, self.n_gyro)
        new = {"q_params": np.asarray(self.si.q_params, float),
               "conv_var": np.asarray(self.si.conv_sigma, float) ** 2,
               "st_sigma": np.asarray(self.si.st_sigma, float)}  # rad, tracker axes, at st_ref_stars
        for name, value in new.items():  # in place (the arrays may be packed, EngineState._pack)
            getattr(self, name)[...] = value
        self._fast_config()
        self._var_cache: dict[int, tuple[np.ndarray, float]] = {}  # see _tracker_var

    # ---------------------------------------------------------------- starts and bumps
    def cold_start(self) -> None:
        """Parameters zero, covariance from the table, attitude from the next valid tracker."""
        self.xp[:] = 0.0
        self.U[:, :] = np.eye(self.ns)
        self.d[:3] = 1.0
        self.d[3:] = np.asarray(self.si.p0_params)
        self.N[:, :] = self.geo.N
        self.parity_queue.clear()
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
    # Every covariance operation of the engine goes through these (UD factors here; the dense
    # reference of tests/oracles/dense_engine.py overrides just these, _regressor_reliability and
    # _vector_update). _cov_close_window is the fused 10 Hz window close (radical_rt.kernels.timeupdate).
    def _cov_reset_attitude(self, P0) -> None:
        """Attitude covariance ← P0 (3, 3), attitude cross-covariances ← 0, the rest kept."""
        self._check(ud.reset_leading_block(self.U, self.d, 3, P0, self.ws.struct))

    def _cov_add_diagonal(self, idx, c) -> None:
        """P[idx_k, idx_k] += c_k (process noise, additive bump)."""
        self._check(ud.add_diagonal_noise(self.U, self.d, idx, c, self.ws.a))

    def _cov_scale(self, s) -> None:
        """P ← diag(s) P diag(s)."""
        self._check(ud.scale_states(self.U, self.d, s))

    def _cov_close_window(self, noise_var: float) -> float:
        """Close the time-update window on the accumulators (:mod:`radical_rt.kernels.timeupdate`): κ
        scaling of Φ_ap, P ← ΦPΦᵀ + diag(Q_aa, 0), parameter noise q·Δt accumulated (added once
        a second), accumulators reset.
        noise_var: increment noise of Θ̂ (see :meth:`_regressor_reliability`). Returns κ."""
        status, kappa = close_time_window(
            self.U, self.d, self.Phi_aa, self.Phi_ap, self.Q_aa, self.th_acc, self.acc_i,
            self.acc_f, self.Minv, self.n_gyro, noise_var, self.si.regressor_k_sigma,
            self.q_params, self.param_idx, self.q_dt, self.ws.struct, self.ws.a)
        self._check(status)
        return kappa

    def _covariance(self) -> np.ndarray:
        """P (ns, ns) from the UD factors (outputs and the excitation monitor only)."""
        P = np.empty((self.ns, self.ns))
        ud.ud_to_cov(self.U, self.d, P)
        return P

    def _begin_attitude_init(self) -> None:
        if getattr(self, "excitation", None) is not None:
            self.excitation.clear()
        self.mode = "init"
        self.att_valid = False
        self._reset_window()

    # ---------------------------------------------------------------- gyro events
    def gyro(self, t, dt, dtheta, status, bridged, var_extra) -> None:
        """Process reconstructed gyro samples (arrays of length m, time order, all ≤ next epoch)."""
        if self.fdi is not None:
            self.fdi.on_gyro(t, dt, dtheta, status, bridged, var_extra)
        self._gyro_body(t, dt, dtheta, status, bridged, var_extra, 0)

    def _gyro_body(self, t, dt, dtheta, status, bridged, var_extra, k: int) -> None:
        """The reference gyro path from sample k (after the FDI hook): gaps, runs, propagation."""
        m = len(t)
        gap_s = self.si.gyro_gap_s
        any_gap = m > k and not dt[k:].max() <= gap_s
        while k < m:
            if not self.att_valid:  # waiting for the first tracker: nothing to propagate
                self.counters["siru_pre_init"] += m - k
                self.t = float(t[m - 1])
                return
            stop = m
            if any_gap:
                gap = np.nonzero(dt[k:] > gap_s)[0]
                stop = m if gap.size == 0 else k + int(gap[0])
            if stop == k:  # a gap: the attitude is lost; warm start, resume at the next tracker
                self.flags |= Flag.GYRO_GAP
                self.counters["gyro_gaps"] += 1
                self.warm_start(bump=False)
                self.t = float(t[k])
                k += 1
                continue
            k = self._propagate(t, dt, dtheta, status, bridged, var_extra, k, stop)

    def _gyro_resume(self, t, dt, dtheta, status, bridged, var_extra) -> None:
        """Continue the reference path inside a run (as :meth:`_propagate` does after a window
        close: to the run's end whatever happened at the close), then from there."""
        gap = np.nonzero(dt > self.si.gyro_gap_s)[0]
        stop = len(dt) if gap.size == 0 else int(gap[0])
        k = self._propagate(t, dt, dtheta, status, bridged, var_extra, 0, stop)
        self._gyro_body(t, dt, dtheta, status, bridged, var_extra, k)

    def _propagate(self, t, dt, dtheta, status, bridged, var_extra, k, stop) -> int:
        if stop < len(dt):
            dtheta, dt, status, bridged = dtheta[:stop], dt[:stop], status[:stop], bridged[:stop]
            var_extra = var_extra[:stop]
        while k < stop:
            k_next, pflags = propagate_window(
                dtheta, dt, status, bridged, var_extra, k,
                self.excluded, self.xp, self.q, self.A, self.geo.W, self.geo.U, self.geo.V,
                self.Minv, self.Gp, self.N, self.Phi_aa, self.Phi_ap, self.Q_aa, self.par_y, self.par_t, self.acc_i,
                self.acc_f, self.th_acc, self.si.prop_window, self.si.arw_var_per_s, self.omega)
            self.counters["siru_used"] += k_next - k
            if pflags & PROP_UNDETERMINED:
                self.counters["siru_undetermined"] += 1
            self.masked = bool(pflags & PROP_MASKED)
            self.t = float(t[k_next - 1])
            k = k_next
            if self.acc_i[0] >= self.si.prop_window:
                self._close_window()
                self._apply_correction()
                self.on_window(self.t)
        return k

    # ---------------------------------------------------------------- window close
    def _reset_window(self) -> None:
        """Reset the time-update and the parity accumulators."""
        self._reset_time_window()
        self._reset_parity()

    def _reset_time_window(self) -> None:
        self.Phi_aa[:, :] = np.eye(3)
        self.Phi_ap[:, :] = 0.0
        self.Q_aa[:, :] = 0.0
        self.acc_i[0] = 0
        self.acc_f[0] = 0.0
        self.th_acc[:] = 0.0

    def _reset_parity(self) -> None:
        self.par_y[:, :] = 0.0
        self.par_t[:, :] = 0.0
        self.acc_i[1:] = 0
        self.acc_f[1:3] = 0.0

    def _regressor_reliability(self, theta, Phi_g, noise_var: float) -> float:
        """Reliability κ ∈ [0, 1] of a summed body increment Θ̂ as the regressor of the λ, μ, du, dv
        columns (errors-in-variables control, docs/engine.md).

        Those columns are linear in the *true* increment Θ; the filter has Θ̂ = Θ + u, where u, with
        covariance S = Φ_g P_gg Φ_gᵀ + noise·(AAᵀ)⁻¹ (Φ_g = ∂Θ̂/∂p̂, P_gg the gyro-parameter
        covariance), does not shrink with Θ: at rest Θ̂ is the bias error and the noise. Used as an
        exact regressor, such a Θ̂ gives the scale factors and misalignments information the data do
        not contain. κ = max(0, 1 − K² s_∥/|Θ̂|²), s_∥ = Θ̂ᵀSΘ̂/|Θ̂|² the variance of u along Θ̂,
        K = ``regressor_k_sigma``: the columns are used in full once the rotation is significant
        at K σ and not at all when it is not (regression calibration of the regressor).
        Computed from the UD factors by :func:`radical_rt.kernels.timeupdate.regressor_reliability`.
        """
        return regressor_reliability(self.U, self.d, 3, theta, Phi_g, self.Minv, noise_var,
                                     self.si.regressor_k_sigma)

    def _scale_regressor_columns(self, M, kappa: float) -> None:
        """Scale the λ, μ, du, dv columns (gyro-parameter order) of M (rows, ≥ 5n columns) by κ."""
        M[:, self.n_gyro:5 * self.n_gyro] *= kappa

    def _close_window(self) -> None:
        """Structured time update, parameter process noise, and the parity sums that are due.

        A parity sum runs over ``parity_window`` samples, across time-update windows and tracker
        epochs (the quantization of the accumulated angle telescopes over it: noise q²/6 per
        contiguous run however long). It measures the (constant) parameters only, so it is kept as
        sufficient statistics and processed ``parity_lag_s`` later, linearized about the estimate
        of that time (:func:`model.parity_from_stats`): its λ, μ, du, dv rows are proportional to
        the body rotation over the sum, whose direction is only as good as the current
        calibration; the lag lets the trackers fix that direction first (docs/engine.md).
        """
        if self.acc_i[0] == 0:
            return
        self.kappa_last[0] = self._cov_close_window(
            self.si.arw_var_per_s * self.acc_f[0] + self.si.quant_var)
        self._close_tail()

    def _close_tail(self) -> None:
        """The rest of a window close after the covariance: lock latch, parity sums."""
        self._update_lock_latch()
        if self.acc_i[1] >= self.si.parity_window:
            self._queue_parity()
            ex = self.excitation  # every 10 s, at the same point on both paths
            if ex is not None and ex.due(self.t):
                self.flags = ex.update(self.t, self._covariance(), self.q, self.conv_var,
                                       self.flags)
        while self.parity_queue and self.parity_queue[0][0] <= self.t - self.si.parity_lag_s:
            self._parity_update(*self.parity_queue.popleft()[1:])

    def flush_parity(self) -> None:
        """End of a stream: process the parity sums still waiting for their lag, then apply."""
        self._queue_parity()
        while self.parity_queue:
            self._parity_update(*self.parity_queue.popleft()[1:])
        self._apply_correction()

    def _queue_parity(self) -> None:
        if self.acc_i[1] > 0 and not self.excluded.any():
            noise = self.acc_f[1] + self.acc_i[2] * self.si.quant_var
            self.parity_queue.append((self.t, self.par_y.copy(), self.par_t.copy(), noise))
            if self.fdi is not None:  # fault detection on this sum's innovation (docs/fdi.md)
                self.fdi.on_parity_sum(self, self.par_y, self.par_t, noise)
        self._reset_parity()

    def _update_lock_latch(self) -> None:
        """Time of the start of the current run of window closes with a locked time line
        (σ_t ≤ timing_consider_s), inf while unlocked. The clock's σ_t can dip below the threshold
        right after its first sawtooth wrap and rise again until the second one; the parity
        calibrates λ, μ, du, dv only after ``parity_lag_s`` of uninterrupted lock, so the trackers
        have calibrated the rotation direction first even when the lock happens in a slew."""
        if self.timing_sigma() > self.si.timing_consider_s:
            self.locked_since = math.inf
        elif self.locked_since == math.inf:
            self.locked_since = self.t

    def _parity_update(self, par_y, par_t, noise: float) -> None:
        """Parity update of one closed sum, linearized about the current estimate."""
        if self.excluded.any():
            return
        nr = self.N.shape[1]
        parity_from_stats(par_y, par_t, self.xp, self.A, self.Gp, self.N, self.geo.W,
                          self.geo.U, self.geo.V, self.z_par, self.H_par, self.theta_par,
                          self.Phi_par)
        self.Hbuf[:nr, :] = 0.0
        self.Hbuf[:nr, 3:] = self.H_par
        consider = None
        if self.t - self.locked_since < self.si.parity_lag_s:
            # The trackers do not calibrate yet (time line not locked), so the direction of the
            # rotation is only as good as the prior calibration: the scale factors and
            # misalignments are consider states of the parity (their signal is kept in S).
            consider = self.scale_mask
        kappa = self._regressor_reliability(self.theta_par, self.Phi_par, noise)
        self.kappa_last[1] = kappa
        if kappa < 1.0:
            self._scale_regressor_columns(self.Hbuf[:nr, 3:], kappa)
        self._vector_update("parity", self.Hbuf[:nr], self.z_par, np.full(nr, noise),
                            self.si.gate_parity_nis, consider)

    def _vector_update(self, kind: str, H, z, rdiag, gate: float, consider=None) -> bool:
        """Gated update with rows H (m, ns); records innovations, σ and NIS for diagnostics.
        consider (ns,) bool: Schmidt consider states (not corrected, covariance kept)."""
        F, S, innov, sig = self._update_views(H.shape[0])
        if consider is None:
            status, nis, edited = gated_update(
                self.U, self.d, self.dx, H, z, rdiag, gate, self.si.edit_enabled, F, S, innov, sig,
                self.ws.f, self.ws.v, self.ws.k)
        else:
            status, nis, edited = gated_update_consider(
                self.U, self.d, self.dx, H, z, rdiag, gate, self.si.edit_enabled, consider, F, S,
                innov, sig, self.ws.f, self.ws.v, self.ws.k, self.ws.a)
        self._check(status)
        return self._update_done(kind, innov.copy(), sig.copy(), float(nis), bool(edited))

    def _update_done(self, kind: str, innov, sig, nis: float, edited: bool) -> bool:
        """Diagnostics, counters and the :attr:`on_update` hook of one measurement update."""
        self.diag_last[kind] = (innov, sig, nis)
        if edited:
            self.counters[kind + "_edited"] += 1
        else:
            self.counters[kind + "_used"] += 1
            self.nis_sum[kind] += nis
        if self.on_update is not None:
            self.on_update(kind, nis, not edited)
        return not edited

    on_update = None  # callable(kind, nis, used) after every measurement update (diagnostics)

    def _update_views(self, m: int) -> tuple[np.ndarray, ...]:
        """Views (F, S, innov, sig) of the update buffers for m rows (made once per m)."""
        v = self._views.get(m)
        if v is None:
            v = self._views[m] = (self.Fbuf[:m], self.Sbuf[:m, :m], self.innov[:m], self.sig[:m])
        return v

    def _correlated_update(self, kind: str, H, z, R, consider=None) -> bool:
        """Gated update with a full noise covariance R (m, m): whitened (ud.decorrelate) rows, then
        :meth:`_vector_update`; the diagnostics are mapped back to physical units."""
        m = H.shape[0]
        Hw, zw, L = self.Hwbuf[:m], self.zwbuf[:m], self.Lbuf[:m, :m]
        self._check(ud.decorrelate(H, z, R, Hw, zw, L))
        used = self._vector_update(kind, Hw, zw, np.ones(m), self.si.gate_st_nis, consider)
        innov_w, _sig_w, nis = self.diag_last[kind]
        innov, sig = np.empty(m), np.empty(m)
        unwhiten_diagnostics(L, innov_w, self.Sbuf[:m, :m], innov, sig)
        self.diag_last[kind] = (innov, sig, nis)
        return used

    def timing_sigma(self) -> float:
        """1σ [s] of the gyro time line at the latest sample (the SIRU clock reconstruction), used
        to add (ω̂·σ_t)² along the rate to the tracker noise; 0 without a source."""
        src = self.timing_sigma_source
        if src is None:
            return 0.0
        sig = float(src())
        return sig if math.isfinite(sig) and sig > 0.0 else 0.0

    timing_sigma_source = None  # callable() → s, e.g. lambda: clock.tag_error_sigma_s

    listener = None  # callable(t) run after every window close (the stream's output scheduler)

    fdi = None  # radical_rt.fdi.monitor.FaultMonitor: hooks on gyro, tracker, parity and window events

    def _apply_correction(self) -> None:
        """Fold dx into the attitude quaternion and the parameters; dx ← 0."""
        g = self.geo  # R⁺ = R(δθ)ᵀ R̂, xp⁺ = xp + δp, geometry rebuilt (one kernel call)
        if fold_correction(self.dx, self.q, self.xp, g.W, g.U, g.V, self.A, self.Minv, self.Gp,
                           self.N) > 0:
            self._numeric("sense-axis geometry singular")

    def state_restored(self) -> None:
        """After :meth:`set_state`: rebuild what derives from xp (scaled axes, (AAᵀ)⁻¹, pseudo-
        inverse), then put the saved parity basis N back (a rebuild re-orthogonalizes N against
        itself, which would change its last bits and break bit-identical resumes)."""
        n_saved = self.N.copy()
        self._refresh()
        self.N[...] = n_saved

    def _refresh(self) -> None:
        status = refresh_axes(self.xp, self.geo.W, self.geo.U, self.geo.V, self.N.copy(), self.A,
                              self.Minv, self.Gp, self.N)
        if status != 0:
            self._numeric("sense-axis geometry singular")

    def apply_isolation(self, gyro: int, state) -> None:
        """Apply the FDI's isolation of ``gyro`` (radical_rt.fdi.monitor): exclude it; with a
        :class:`radical_rt.fdi.monitor.Reconfiguration` ``state``, take its U, d, xp, q, omega and add
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
            self._check(ud.add_diagonal_noise(self.U, self.d, self.param_idx,
                                              self.q_params * state.dt_noise, self.ws.a))
        else:
            self.warm_start(bump=False)
        self.dx[:] = 0.0
        self.parity_queue.clear()
        self._reset_parity()
        self._refresh()

    # ---------------------------------------------------------------- tracker events
    def tracker(self, j: int, t_epoch: float, q_meas, n_stars: int, valid: bool) -> bool:
        """Star tracker j (1 or 2) sample at epoch t_epoch (gyro time line), reference path
        (the stream's releases run :meth:`release`). Returns True if used."""
        if not valid or n_stars < self.si.st_min_stars:
            self.counters[f"st{j}_invalid"] += 1
            return False
        self.last_valid_st[j] = t_epoch
        if self.fdi is not None:
            self.fdi.on_tracker(j, t_epoch, q_meas, n_stars)
        if not self.att_valid:
            return self._init_attitude(j, t_epoch, q_meas, n_stars)
        self._close_window()
        used = self._tracker_update(j, t_epoch, q_meas, n_stars)
        self._apply_correction()
        self.on_window(t_epoch)
        return used

    def latency_residual(self) -> float:
        """Residual tracker latency estimate τ̂ [s] (true − configured)."""
        return float(self.xp[self.layout["lat"].start - 3])

    def latency_estimate(self) -> dict[str, float]:
        """Tracker latency: configured, residual τ̂ and total estimate, with the 1σ of τ [s]."""
        k = self.layout["lat"].start
        ud.variances(self.U, self.d, self.ws.var)
        tau = self.latency_residual()
        return {"configured_s": float(self.si.latency_st_s), "residual_s": tau,
                "estimate_s": float(self.si.latency_st_s) + tau,
                "sigma_s": float(math.sqrt(max(self.ws.var[k], 0.0)))}

    def _tracker_sigma(self, n_stars: int) -> np.ndarray:
        return self.st_sigma * math.sqrt(self.si.st_ref_stars / max(n_stars, 1))

    def _tracker_var(self, n_stars: int) -> tuple[np.ndarray, float]:
        """Tracker noise variances (3,) [rad², tracker axes] for n_stars, and their minimum
        (cached per star count until the parameters change)."""
        hit = self._var_cache.get(n_stars)
        if hit is None:
            rdiag = self._tracker_sigma(n_stars) ** 2
            hit = self._var_cache[n_stars] = (rdiag, float(rdiag.min()))
        return hit

    def _mounting(self, j: int):
        if j == 1:
            return self.geo.R_st1_from_body, False
        return self.geo.R_st2_from_body_nom, True

    def _init_attitude(self, j: int, t_epoch: float, q_meas, n_stars: int) -> bool:
        if j == 2 and t_epoch - self.last_valid_st.get(1, -math.inf) < self.si.st_stale_s:
            return False  # prefer ST1 as long as it is alive
        R_nom, use_phi = self._mounting(j)
        phi = self.xp[param_slice(self.layout, "phi2")]
        self.q[:] = quat_from_tracker(np.asarray(q_meas, float), R_nom, phi, use_phi)
        sig_body = np.abs(R_nom.T) @ (self._tracker_sigma(n_stars) * self.si.att_init_scale)
        P0 = np.diag(sig_body**2)
        if use_phi:
            P0 += np.diag(self.variances()[self.layout["phi2"]])
        self._cov_reset_attitude(P0)
        self.att_valid = True
        self.t = t_epoch
        self.mode = "converging"
        self.flags &= ~int(Flag.GYRO_GAP)
        self._reset_window()
        self.counters["att_inits"] += 1
        return True

    def _tracker_rows(self, j: int, t_epoch: float, q_meas) -> tuple[np.ndarray, np.ndarray]:
        """Residual of tracker j at t_epoch (configured-latency epoch on the gyro time line) into
        self.r3 (tracker axes, rad) and its rows H (3, ns); returns (H, R_st_from_body_nominal).
        The measurement refers to t_epoch − τ̂ (τ: residual latency state): the attitude is
        extrapolated from the last sample to that time with the body rate
        (:func:`model.tracker_rows`; ∂h/∂τ is checked by finite differences in test_latency.py)."""
        R_nom, use_phi = self._mounting(j)
        H = self.Hbuf[:3]
        self._rate2 = tracker_rows(
            np.asarray(q_meas, float), self.q, self.omega, t_epoch - self.latency_residual() - self.t,
            R_nom, self.xp[self._phi_p], use_phi, self._phi_col, self._lat_col, self.r3, self.H_att,
            self.H_phi, H)
        return H, R_nom

    def _tracker_update(self, j: int, t_epoch: float, q_meas, n_stars: int) -> bool:
        H, R_nom = self._tracker_rows(j, t_epoch, q_meas)
        kind = ST_KIND[j]
        rdiag, rmin = self._tracker_var(n_stars)
        sig_t = self.timing_sigma()
        # |R ω̂|² = |ω̂|²: attitude error per second of epoch error, tracker axes [rad/s]
        ratio = sig_t * sig_t * self._rate2 / rmin
        if ratio > 1e-4:  # below, the timing term is < 0.01 % of the tracker variance
            # Epoch error δt of the gyro time line → attitude error R ω̂ δt (rank one in tracker
            # axes). While it is not small against the tracker noise (clock not locked, body
            # turning), it is a slowly varying bias, not white noise: the tracker then keeps the
            # attitude (and φ2) but does not calibrate the gyros (Schmidt consider).
            consider = self.gyro_mask if sig_t > self.si.timing_consider_s else None
            if consider is not None:
                self.counters[kind + "_consider"] += 1
            R = np.empty((3, 3))
            timing_noise(R_nom, self.omega, rdiag, sig_t, R)
            used = self._correlated_update(kind, H, self.r3, R, consider)
        else:
            used = self._vector_update(kind, H, self.r3, rdiag, self.si.gate_st_nis)
        bit = ST_EDITED_BIT[j]
        self.flags = (self.flags & ~bit) | (0 if used else bit)
        return used

    # ---------------------------------------------------------------- health
    def _check(self, status: int) -> None:
        if status != 0:
            self._numeric(f"UD kernel status {status}")

    def _numeric(self, why: str) -> None:
        """Numerical-integrity failure: flag it and recover with a cold start of the covariance."""
        self.flags |= Flag.NUMERIC
        self.counters["numeric_faults"] += 1
        self.last_numeric = why
        if not (np.all(np.isfinite(self.d)) and np.all(self.d > 0) and np.all(np.isfinite(self.xp))):
            self.xp[:] = np.where(np.isfinite(self.xp), self.xp, 0.0)
            self.U[:, :] = np.eye(self.ns)
            self.d[3:] = np.asarray(self.si.p0_params)
            self._begin_attitude_init()

    def on_window(self, t: float) -> None:
        """Hook after every window close (10 Hz, deterministic points): mode, flags, convergence."""
        if self.fdi is not None:
            self.fdi.on_window(self, t)
        self.update_mode(t)
        if self.listener is not None:
            self.listener(t)


__all__ = ["Engine", "PARAM_GROUPS"]
