"""The engine's steps written out in Python: a test oracle, not the product.

:class:`ReferenceEngine` is :class:`radical_rt.engine.filter.Engine` with :meth:`release` replaced
by an event loop in Python that calls the small kernels one by one (propagation, window close,
parity sums, tracker updates, fold), in the order docs/engine.md §3 specifies. The product runs
the same steps compiled in one call (:mod:`radical_rt.engine.loop`,
:mod:`radical_rt.engine.steps`); tests/radical_rt/engine/test_fastpath.py requires the two to give
the same outputs bit for bit, so each is a check on the other. The dense-covariance oracle (:mod:`tests.oracles.dense_engine`) runs
this loop with its own covariance primitives. Shared with the product on purpose: the kernels of
:mod:`radical_rt.kernels`, the commands and starts, and the window hook (``Engine.on_window``).
"""

from __future__ import annotations

import math

import numpy as np

from radical_rt.contract.flags import Flag
from radical_rt.engine.engine_state import param_slice
from radical_rt.engine.filter import Engine
from radical_rt.engine.shell import ST_EDITED_BIT, ST_KIND
from radical_rt.kernels import ud
from radical_rt.kernels.model import fold_correction, parity_from_stats
from radical_rt.kernels.propagate import (
    PROP_MASKED,
    PROP_UNDETERMINED,
    SampleWork,
    propagate_window,
)
from radical_rt.kernels.timeupdate import close_time_window, regressor_reliability
from radical_rt.kernels.tracker_model import quat_from_tracker, tracker_rows
from radical_rt.kernels.updates import (
    gated_update,
    gated_update_consider,
    timing_noise,
    unwhiten_diagnostics,
)


def _span(arrays, a: int, b: int):
    """Samples a..b−1 of gyro arrays (t, dt, dtheta, status, bridged, var_extra), as views."""
    return tuple(x[a:b] for x in arrays)


class ReferenceEngine(Engine):
    """:class:`Engine` whose releases run the Python event loop of this module."""

    def __init__(self, table=None, geometry=None, **options) -> None:
        super().__init__(table, geometry, **options)
        self.queue: list = []  # closed parity sums waiting for their lag (t, y, tt, noise)
        self._views: dict[int, tuple[np.ndarray, ...]] = {}
        self._var_cache: dict[int, tuple[np.ndarray, float]] = {}
        n, ns = self.n_gyro, self.ns
        self._fz, self._fH = np.zeros(1), np.zeros((1, ns - 3))
        self._fth, self._fPhi, self._fh = np.zeros(3), np.zeros((3, 5 * n)), np.zeros(ns)

    def params_changed(self) -> None:
        super().params_changed()
        self._var_cache = {}

    def cold_start(self) -> None:
        super().cold_start()
        self.queue = []

    def apply_isolation(self, gyro: int, state) -> None:
        super().apply_isolation(gyro, state)
        self.queue = []

    @property
    def parity_queue(self):
        return [(t, y.copy(), tt.copy(), nz) for t, y, tt, nz in getattr(self, "queue", [])]

    def set_parity_queue(self, items, rows: int = 0) -> None:
        self.queue = [(t, np.array(y, float), np.array(tt, float), nz) for t, y, tt, nz in items]

    def _event(self, code: int, arg: int = 0, t: float = 0.0) -> None:
        """The engine's compiled step, after the bookkeeping this oracle keeps in Python (last
        tracker epochs, NIS sums) is put into the kernel's io."""
        self._load_bookkeeping()
        super()._event(code, arg, t)

    def update_mode(self, t: float) -> None:
        """Stale-tracker flags, convergence test on the UD variances, and the mode."""
        stale_bits = ((1, int(Flag.ST1_STALE)), (2, int(Flag.ST2_STALE)))
        not_converged, numeric = int(Flag.NOT_CONVERGED), int(Flag.NUMERIC)
        f, stale_s, last = self.flags, self.si.st_stale_s, self.last_valid_st
        for j, bit in stale_bits:
            f = (f | bit) if t - last.get(j, -math.inf) > stale_s else (f & ~bit)
        if not self.att_valid:
            self.flags, self.mode = f, "init"
            return
        conv = self._cov_converged()
        f = (f & ~not_converged) if conv else (f | not_converged)
        self.flags = f
        if f & numeric or self.excluded.any():
            self.mode = "degraded"
        else:
            self.mode = "converged" if conv else "converging"

    def _cov_converged(self) -> bool:
        """Every parameter variance within its convergence threshold (UD variances, P not formed;
        the dense reference overrides it)."""
        return bool(ud.variances_within(self.U, self.d, self.ws.var, self.conv_var, 3))

    # ---------------------------------------------------------------- the event loop
    def release(self, arrays, a: int, z: int, events, predict=None) -> None:
        """As Engine.release: the FDI history first, then per tracker event the gyro samples up
        to its epoch and the sample, then the samples up to z (no prediction is made)."""
        self.locked = self.timing_sigma() <= self.si.timing_consider_s
        if self.fdi is not None and z > a:
            self.fdi.on_gyro_rows(arrays, a, z)
        t = arrays[0]
        k = a
        for ev in events:
            up = k + int(np.searchsorted(t[k:z], ev[1], side="right"))
            if up > k:
                self._gyro_body(*_span(arrays, k, up))
            k = up
            self.tracker(*ev)
        if z > k:
            self._gyro_body(*_span(arrays, k, z))

    def _gyro_body(self, t, dt, dtheta, status, bridged, var_extra) -> None:
        """Gyro samples: counted before an attitude exists; a gap loses the attitude (warm start
        without bump); runs between gaps propagated, stopping when a close loses the attitude."""
        m, k = len(t), 0
        gap_s = self.si.gyro_gap_s
        while k < m:
            if not self.att_valid:
                self.counters["siru_pre_init"] += m - k
                self.t = float(t[m - 1])
                return
            if dt[k] > gap_s:
                self.flags |= Flag.GYRO_GAP
                self.counters["gyro_gaps"] += 1
                self.warm_start(bump=False)
                self.t = float(t[k])
                k += 1
                continue
            gap = np.nonzero(dt[k:] > gap_s)[0]
            stop = m if gap.size == 0 else k + int(gap[0])
            k = self._propagate(t, dt, dtheta, status, bridged, var_extra, k, stop)

    def _propagate(self, t, dt, dtheta, status, bridged, var_extra, k, stop) -> int:
        dtheta, dt, status, bridged = dtheta[:stop], dt[:stop], status[:stop], bridged[:stop]
        var_extra = var_extra[:stop]
        while k < stop and self.att_valid:
            k_next, pflags = propagate_window(
                dtheta, dt, status, bridged, var_extra, k, stop, self.excluded, self.xp, self.q,
                self.A, self.geo.W, self.geo.U, self.geo.V, self.Minv, self.Gp, self.N,
                self.Phi_aa, self.Phi_ap, self.Q_aa, self.par_y, self.par_t, self.acc_i,
                self.acc_f, self.th_acc, self.si.prop_window, self.si.arw_var_per_s, self.omega,
                SampleWork(**vars(self.pw)))
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

    def _apply_correction(self) -> None:
        """Fold dx into the attitude quaternion and the parameters; dx ← 0 (the loop's steps.fold)."""
        g = self.geo  # R⁺ = R(δθ)ᵀ R̂, xp⁺ = xp + δp, geometry rebuilt (one kernel call)
        if fold_correction(self.dx, self.q, self.xp, g.W, g.U, g.V, self.A, self.Minv, self.Gp,
                           self.N) > 0:
            self._numeric("sense-axis geometry singular")

    def _cov_close_window(self, noise_var: float) -> float:
        status, kappa = close_time_window(
            self.U, self.d, self.Phi_aa, self.Phi_ap, self.Q_aa, self.th_acc, self.acc_i,
            self.acc_f, self.Minv, self.n_gyro, noise_var, self.si.regressor_k_sigma,
            self.q_params, self.param_idx, self.q_dt, self.ws.struct, self.ws.a)
        self._check(status)
        return kappa

    def _close_window(self) -> None:
        if self.acc_i[0] == 0:
            return
        self.kappa_last[0] = self._cov_close_window(
            self.si.arw_var_per_s * self.acc_f[0] + self.si.quant_var)
        self._close_tail()

    def _close_tail(self) -> None:
        """Lock latch, the parity sum when complete, the queued sums whose lag has passed."""
        if self.timing_sigma() > self.si.timing_consider_s:
            self.locked_since = math.inf
        elif self.locked_since == math.inf:
            self.locked_since = self.t
        if self.acc_i[1] >= self.si.parity_window:
            self._queue_parity()
        while self.queue and self.queue[0][0] <= self.t - self.si.parity_lag_s:
            self._parity_update(*self.queue.pop(0)[1:])

    def flush_parity(self) -> None:
        self._queue_parity()
        while self.queue:
            self._parity_update(*self.queue.pop(0)[1:])
        self._apply_correction()
        pending, self._sum_pending = self._sum_pending, None
        if pending is not None and self.fdi is not None:
            self.fdi.on_parity_sum(self, pending)

    def _queue_parity(self) -> None:
        if self.acc_i[1] > 0 and not self.excluded.any():
            noise = self.acc_f[1] + self.acc_i[2] * self.si.quant_var
            self.queue.append((self.t, self.par_y.copy(), self.par_t.copy(), noise))
            fdi_on = self.fdi is not None and self.fdi.enabled(self)
            self._sum_pending = self._fdi_statistic(noise) if fdi_on else ()
        self._reset_parity()

    def _fdi_statistic(self, noise: float) -> tuple:
        """(ν, ρ, t0, z) of the sum in par_y, par_t (docs/fdi.md §2), () when not finite."""
        parity_from_stats(self.par_y, self.par_t, self.xp, self.A, self.Gp, self.N, self.geo.W,
                          self.geo.U, self.geo.V, self._fz, self._fH, self._fth, self._fPhi)
        h = self._fh
        h[3:] = self._fH[0]
        f = self.U.T @ h
        s2 = float(self.d @ (f * f)) + noise
        z = float(self._fz[0] - h @ self.dx)
        if not (s2 > 0.0 and noise > 0.0 and math.isfinite(z)):
            return ()
        return z / math.sqrt(s2), s2 / noise, float(self.t) - float(self.acc_f[2]), z

    def _parity_update(self, par_y, par_t, noise: float) -> None:
        if self.excluded.any():
            return
        nr = self.N.shape[1]
        parity_from_stats(par_y, par_t, self.xp, self.A, self.Gp, self.N, self.geo.W,
                          self.geo.U, self.geo.V, self.z_par, self.H_par, self.theta_par,
                          self.Phi_par)
        self.Hbuf[:nr, :] = 0.0
        self.Hbuf[:nr, 3:] = self.H_par
        consider = self.scale_mask if self.t - self.locked_since < self.si.parity_lag_s else None
        kappa = self._regressor_reliability(self.theta_par, self.Phi_par, noise)
        self.kappa_last[1] = kappa
        if kappa < 1.0:
            self._scale_regressor_columns(self.Hbuf[:nr, 3:], kappa)
        self._vector_update("parity", self.Hbuf[:nr], self.z_par, np.full(nr, noise),
                            self.si.gate_parity_nis, consider)

    def _regressor_reliability(self, theta, Phi_g, noise_var: float) -> float:
        return regressor_reliability(self.U, self.d, 3, theta, Phi_g, self.Minv, noise_var,
                                     self.si.regressor_k_sigma)

    def _scale_regressor_columns(self, M, kappa: float) -> None:
        """Scale the λ, μ, du, dv columns (gyro-parameter order) of M (rows, ≥ 5n columns) by κ."""
        M[:, self.n_gyro:5 * self.n_gyro] *= kappa

    # ---------------------------------------------------------------- updates
    def _vector_update(self, kind: str, H, z, rdiag, gate: float, consider=None) -> bool:
        m = H.shape[0]
        v = self._views.get(m)
        if v is None:
            v = self._views[m] = (self.Fbuf[:m], self.Sbuf[:m, :m], self.innov[:m], self.sig[:m])
        F, S, innov, sig = v
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

    def _correlated_update(self, kind: str, H, z, R, consider=None) -> bool:
        m = H.shape[0]
        Hw, zw, L = self.Hwbuf[:m], self.zwbuf[:m], self.Lbuf[:m, :m]
        self._check(ud.decorrelate(H, z, R, Hw, zw, L))
        used = self._vector_update(kind, Hw, zw, np.ones(m), self.si.gate_st_nis, consider)
        innov_w, _sig_w, nis = self.diag_last[kind]
        innov, sig = np.empty(m), np.empty(m)
        unwhiten_diagnostics(L, innov_w, self.Sbuf[:m, :m], innov, sig)
        self.diag_last[kind] = (innov, sig, nis)
        return used

    # ---------------------------------------------------------------- tracker events
    def tracker(self, j: int, t_epoch: float, q_meas, n_stars: int, valid: bool) -> bool:
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

    def _tracker_sigma(self, n_stars: int) -> np.ndarray:
        return self.st_sigma * math.sqrt(self.si.st_ref_stars / max(n_stars, 1))

    def _tracker_var(self, n_stars: int) -> tuple[np.ndarray, float]:
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
        self._reset_time_window()
        self._reset_parity()
        self.counters["att_inits"] += 1
        return True

    def _tracker_rows(self, j: int, t_epoch: float, q_meas) -> tuple[np.ndarray, np.ndarray]:
        """Residual of tracker j at t_epoch into self.r3 and its rows H (3, ns); returns (H,
        R_st_from_body_nominal)."""
        R_nom, use_phi = self._mounting(j)
        H = self.Hbuf[:3]
        self._rate2 = tracker_rows(
            np.asarray(q_meas, float), self.q, self.omega, t_epoch - self.latency_residual() - self.t,
            R_nom, self.xp[self._phi_col - 3:self._phi_col], use_phi, self._phi_col,
            self._lat_col, self.r3, self.H_att, self.H_phi, H)
        return H, R_nom

    def _tracker_update(self, j: int, t_epoch: float, q_meas, n_stars: int) -> bool:
        H, R_nom = self._tracker_rows(j, t_epoch, q_meas)
        kind = ST_KIND[j]
        rdiag, rmin = self._tracker_var(n_stars)
        sig_t = self.timing_sigma()
        if sig_t * sig_t * self._rate2 / rmin > 1e-4:
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
