"""The RADICAL engine: cold/warm start, propagation, parity and tracker updates, editing, bumps.

The engine is driven by events in time order (see :mod:`radical_rt.stream`): gyro batches
(:class:`radical_rt.clock.GyroBatch`, reconstructed sample times) and tracker samples at their
epoch on the gyro time line. It holds only UD factors (U, d) of the covariance; full covariance
entries are computed for outputs only. All numbers SI; see :mod:`radical_rt.conventions`.

Cycle (notes §14): samples are propagated one by one (:func:`propagate.propagate_window`); every
``parity_window`` samples, or at a tracker epoch, the window closes: structured UD time update,
parameter process noise (Agee-Turner), the parity (null-space) update; at a tracker epoch the three
tracker residual components follow as scalar Bierman updates after a joint χ² edit test. The
correction is then folded into the attitude quaternion and the parameters.
"""

from __future__ import annotations

import math

import numpy as np

from . import ud
from .engine_state import EngineState, _psl
from .flags import Flag
from .geometry import Geometry
from .model import apply_body_rotation, quat_from_tracker, refresh_geometry, tracker_residual
from .params import ParamTable, to_si
from .propagate import PROP_MASKED, PROP_UNDETERMINED, propagate_window
from .rotation import quat_conj, quat_mul, rotvec_to_quat
from .state import PARAM_GROUPS, StateLayout
from .updates import gated_update


class Engine(EngineState):
    """The 3 + 5n + 3 state UD-factorized RADICAL filter (n gyros, ST1 reference, ST2 relative)."""

    def __init__(self, table: ParamTable | None = None, geometry: Geometry | None = None) -> None:
        geometry = geometry or Geometry()
        super().__init__(StateLayout(geometry.n_gyro), geometry)
        self.table = table or ParamTable(n_gyro=geometry.n_gyro)
        self.params_changed()
        self.cold_start()

    # ---------------------------------------------------------------- configuration
    def params_changed(self) -> None:
        """Re-read the active parameter table (called after set/reset of parameters)."""
        self.si = to_si(self.table.active, self.n_gyro)
        self.q_params = np.asarray(self.si.q_params)

    # ---------------------------------------------------------------- starts and bumps
    def cold_start(self) -> None:
        """Parameters zero, covariance from the table, attitude from the next valid tracker."""
        self.xp[:] = 0.0
        self.U[:, :] = np.eye(self.ns)
        self.d[:3] = 1.0
        self.d[3:] = np.asarray(self.si.p0_params)
        self.N[:, :] = self.geo.N
        self._refresh()
        self._begin_attitude_init()
        self.counters["cold_starts"] += 1

    def warm_start(self, bump: bool = True) -> None:
        """Reset attitude and its cross-covariance, keep the parameter UD factors; bump them."""
        status = ud.reset_leading_block(self.U, self.d, 3, np.eye(3), self.ws.struct)
        self._check(status)
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
            self._check(ud.add_diagonal_noise(self.U, self.d, np.asarray(idx, np.int64),
                                              np.asarray(c), self.ws.a))
        else:  # same diagonal increase, applied as σ scaling so correlations are kept
            var = self.variances()
            s = np.ones(self.ns)
            for group, values in sigma.items():
                sl = self.layout[group]
                s[sl] = np.sqrt(1.0 + np.asarray(values, float) ** 2 / var[sl])
            self._check(ud.scale_states(self.U, self.d, s))
        self.counters["bumps"] += 1

    def _begin_attitude_init(self) -> None:
        self.mode = "init"
        self.att_valid = False
        self._reset_window()

    # ---------------------------------------------------------------- gyro events
    def gyro(self, t, dt, dtheta, status, bridged, var_extra) -> None:
        """Process reconstructed gyro samples (arrays of length m, time order, all ≤ next epoch)."""
        m = len(t)
        k = 0
        while k < m:
            if not self.att_valid:  # waiting for the first tracker: nothing to propagate
                self.counters["siru_pre_init"] += m - k
                self.t = float(t[m - 1])
                return
            gap = np.nonzero(dt[k:] > self.si.gyro_gap_s)[0]
            stop = m if gap.size == 0 else k + int(gap[0])
            if stop == k:  # a gap: the attitude is lost; warm start, resume at the next tracker
                self.flags |= Flag.GYRO_GAP
                self.counters["gyro_gaps"] += 1
                self.warm_start(bump=False)
                self.t = float(t[k])
                k += 1
                continue
            k = self._propagate(t, dt, dtheta, status, bridged, var_extra, k, stop)

    def _propagate(self, t, dt, dtheta, status, bridged, var_extra, k, stop) -> int:
        while k < stop:
            k_next, pflags = propagate_window(
                dtheta[:stop], dt[:stop], status[:stop], bridged[:stop], var_extra[:stop], k,
                self.excluded, self.xp, self.q, self.Wt, self.dWdu, self.dWdv, self.Minv, self.Gp,
                self.N, self.Phi_aa, self.Phi_ap, self.Q_aa, self.z_par, self.H_par, self.acc_i,
                self.acc_f, self.si.parity_window, self.si.arw_var_per_s, self.omega)
            self.counters["siru_used"] += k_next - k
            if pflags & PROP_UNDETERMINED:
                self.counters["siru_undetermined"] += 1
            self.masked = bool(pflags & PROP_MASKED)
            self.t = float(t[k_next - 1])
            k = k_next
            if self.acc_i[0] >= self.si.parity_window:
                self._close_window()
                self._apply_correction()
                self.on_window(self.t)
        return k

    # ---------------------------------------------------------------- window close
    def _reset_window(self) -> None:
        self.Phi_aa[:, :] = np.eye(3)
        self.Phi_ap[:, :] = 0.0
        self.Q_aa[:, :] = 0.0
        self.z_par[:] = 0.0
        self.H_par[:, :] = 0.0
        self.acc_i[:] = 0
        self.acc_f[:] = 0.0

    def _close_window(self) -> None:
        """Structured time update, parameter process noise and the parity update."""
        if self.acc_i[0] == 0:
            return
        self._check(ud.structured_time_update(self.U, self.d, 3, self.Phi_aa, self.Phi_ap,
                                              self.Q_aa, self.ws.struct))
        self._check(ud.add_diagonal_noise(self.U, self.d, self.param_idx,
                                          self.q_params * self.acc_f[0], self.ws.a))
        if self.acc_i[1] > 0 and not self.excluded.any():
            nr = self.N.shape[1]
            self.Hbuf[:nr, :] = 0.0
            self.Hbuf[:nr, 3:] = self.H_par
            rd = np.full(nr, self.acc_f[1] + self.si.quant_var)
            self._vector_update("parity", self.Hbuf[:nr], self.z_par, rd, self.si.gate_parity_nis)
        self._reset_window()

    def _vector_update(self, kind: str, H, z, rdiag, gate: float) -> bool:
        """Gated update with rows H (m, ns); records innovations, σ and NIS for diagnostics."""
        m = H.shape[0]
        status, nis, edited = gated_update(
            self.U, self.d, self.dx, H, z, rdiag, gate, self.si.edit_enabled, self.Fbuf[:m],
            self.Sbuf[:m, :m], self.innov[:m], self.sig[:m], self.ws.f, self.ws.v, self.ws.k)
        self._check(status)
        self.diag_last[kind] = (self.innov[:m].copy(), self.sig[:m].copy(), float(nis))
        if edited:
            self.counters[f"{kind}_edited"] += 1
            return False
        self.counters[f"{kind}_used"] += 1
        self.nis_sum[kind] += nis
        return True

    def _apply_correction(self) -> None:
        """Fold dx into the attitude quaternion and the parameters; dx ← 0."""
        if not np.any(self.dx):
            return
        dth = self.dx[:3]
        self.q[:] = quat_mul(quat_conj(rotvec_to_quat(dth)), self.q)  # R⁺ = R(δθ)ᵀ R̂
        self.q /= np.linalg.norm(self.q) * (1.0 if self.q[3] >= 0 else -1.0)
        self.xp += self.dx[3:]
        self.dx[:] = 0.0
        self._refresh()

    def _refresh(self) -> None:
        status = refresh_geometry(self.xp, self.geo.W, self.geo.U, self.geo.V, self.N.copy(),
                                  self.Wt, self.dWdu, self.dWdv, self.Minv, self.Gp, self.N)
        if status != 0:
            self._numeric("sense-axis geometry singular")

    # ---------------------------------------------------------------- tracker events
    def tracker(self, j: int, t_epoch: float, q_meas, n_stars: int, valid: bool) -> bool:
        """Star tracker j (1 or 2) sample at epoch t_epoch (gyro time line). Returns True if used."""
        if not valid or n_stars < self.si.st_min_stars:
            self.counters[f"st{j}_invalid"] += 1
            return False
        self.last_valid_st[j] = t_epoch
        if not self.att_valid:
            return self._init_attitude(j, t_epoch, q_meas, n_stars)
        self._close_window()
        used = self._tracker_update(j, t_epoch, q_meas, n_stars)
        self._apply_correction()
        self.on_window(t_epoch)
        return used

    def _tracker_sigma(self, n_stars: int) -> np.ndarray:
        return np.asarray(self.si.st_sigma) * math.sqrt(self.si.st_ref_stars / max(n_stars, 1))

    def _mounting(self, j: int):
        if j == 1:
            return self.geo.R_st1_from_body, False
        return self.geo.R_st2_from_body_nom, True

    def _init_attitude(self, j: int, t_epoch: float, q_meas, n_stars: int) -> bool:
        if j == 2 and t_epoch - self.last_valid_st.get(1, -math.inf) < self.si.st_stale_s:
            return False  # prefer ST1 as long as it is alive
        R_nom, use_phi = self._mounting(j)
        phi = self.xp[_psl(self.layout, "phi2")]
        self.q[:] = quat_from_tracker(np.asarray(q_meas, float), R_nom, phi, use_phi)
        sig_body = np.abs(R_nom.T) @ (self._tracker_sigma(n_stars) * self.si.att_init_scale)
        P0 = np.diag(sig_body**2)
        if use_phi:
            P0 += np.diag(ud_var_block(self, "phi2"))
        self._check(ud.reset_leading_block(self.U, self.d, 3, P0, self.ws.struct))
        self.att_valid = True
        self.t = t_epoch
        self.mode = "converging"
        self.flags &= ~int(Flag.GYRO_GAP)
        self._reset_window()
        self.counters["att_inits"] += 1
        return True

    def _tracker_update(self, j: int, t_epoch: float, q_meas, n_stars: int) -> bool:
        R_nom, use_phi = self._mounting(j)
        q_epoch = self.q.copy()
        tau = t_epoch - self.t  # extrapolate the attitude from the last sample to the epoch
        if tau != 0.0:
            apply_body_rotation(q_epoch, self.omega * tau, np.empty(4), np.empty(4))
        phi = self.xp[_psl(self.layout, "phi2")]
        tracker_residual(np.asarray(q_meas, float), q_epoch, R_nom, phi, use_phi, self.r3,
                         self.H_att, self.H_phi)
        H = self.Hbuf[:3]
        H[:, :] = 0.0
        H[:, :3] = self.H_att
        H[:, self.layout["phi2"]] = self.H_phi
        used = self._vector_update(f"st{j}", H, self.r3, self._tracker_sigma(n_stars) ** 2,
                                   self.si.gate_st_nis)
        bit = Flag.ST1_EDITED if j == 1 else Flag.ST2_EDITED
        self.flags = (self.flags & ~int(bit)) | (0 if used else int(bit))
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

    listener = None  # callable(t) run after every window close (the stream's output scheduler)

    def on_window(self, t: float) -> None:
        """Hook after every window close (10 Hz, deterministic points): mode, flags, convergence."""
        self.update_mode(t)
        if self.listener is not None:
            self.listener(t)


def ud_var_block(engine: Engine, group: str) -> np.ndarray:
    """Variances (SI²) of one parameter group from the UD factors, without forming P."""
    ud.variances(engine.U, engine.d, engine.ws.var)
    return engine.ws.var[engine.layout[group]].copy()


__all__ = ["Engine", "PARAM_GROUPS"]
