"""Dense-covariance reference of the RADICAL engine (same filter, P instead of U, d).

:class:`DenseEngine` subclasses :class:`radical_rt.engine.filter.Engine` and overrides only the
engine's covariance primitives (``_cov_reset_attitude``, ``_cov_add_diagonal``, ``_cov_scale``,
``_cov_close_window``, ``_cov_converged``), the regressor reliability (from P, an independent
implementation of its formula), ``_vector_update`` and ``variances``/``contract_params``; models,
Jacobians, propagation, parity statistics, gating, consider logic, corrections and the order of
every operation are the engine's own. The
covariance P (ns, ns) is the single source of truth:

============================  =================================  ==================================
engine operation              UD engine (kernels.ud, ud_time, updates)  here
============================  =================================  ==================================
window time update            structured_time_update (MWGS-free  P ← ΦPΦᵀ + Q, Φ = [[Φ_aa, Φ_ap],
                              attitude-first partition)          [0, I]] (exploits the same blocks)
parameter process noise       add_diagonal_noise (Agee-Turner)   P_ii += q_i Δt
tracker / parity update       gated_update[_consider] (Bierman,  NIS from S = HPHᵀ + R, then per
                              Agee-Turner for consider states)   row the Joseph form with the
                                                                 Schmidt gain (consider rows of K
                                                                 zeroed): P ← (I−khᵀ)P(I−khᵀ)ᵀ+rkkᵀ
warm start / attitude init    reset_leading_block                P_aa ← P0, P_ap ← 0
bump                          add_diagonal_noise / scale_states  P_ii += σ², or P ← SPS
variances, contract σ         variances / ud_to_cov              diag(P), P
============================  =================================  ==================================

The Joseph form is evaluated as the equivalent symmetric rank-two update
``P − k bᵀ − b kᵀ + α k kᵀ`` with ``b = P h``, ``α = hᵀb + r`` (no n³ products); with the
Schmidt gain (k zero on the consider states) it gives exactly the UD engine's consider update.

Code that still reads ``engine.U`` / ``engine.d`` (checkpoints, the FDI snapshots, the stream's
``diag`` message, ``latency_estimate``) gets a UD factorization of P computed on demand. Code that
*writes* the factors in place outside the methods overridden here (the FDI reconfiguration after a
gyro failure) is not supported: this is a reference for fault-free runs and benchmarks.

The dense kernels are in :mod:`tests.oracles.dense_kernels`.

Command (the same run through both engines, final estimates compared)::

    python -m tests.oracles.dense_engine [--duration 300] [--seed 1]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from radical_rt._jit import OK
from radical_rt.contract.flags import Flag
from radical_rt.engine.filter import Engine
from radical_rt.kernels import ud
from radical_rt.kernels.parametrization import contract_from_internal
from radical_rt.kernels.timeupdate import ACC_NOISE_T, NOISE_PERIOD_S
from tests.oracles.dense_kernels import (
    dense_add_diagonal,
    dense_gated_update,
    dense_reset_leading,
    dense_time_update,
)
from tests.oracles.reference_engine import ReferenceEngine


class DenseEngine(ReferenceEngine):
    """The Python event loop of :class:`ReferenceEngine` with the covariance kept dense (see the
    module docstring)."""

    def __init__(self, table=None, geometry=None, **options) -> None:
        self.P = np.zeros((0, 0))  # allocated by the first cold start (_from_ud)
        self._ud_synced = True
        super().__init__(table, geometry, **options)
        ns = self.ns
        self._T = np.zeros((3, ns))
        self._PHt = np.zeros((ns, self.Hbuf.shape[0]))
        self._b = np.zeros(ns)
        self._k = np.zeros(ns)
        self._no_consider = np.zeros(ns, dtype=np.bool_)

    # ---------------------------------------------------------- U, d: derived views of P
    @property
    def U(self) -> np.ndarray:
        if not self._ud_synced:
            self._factor()
        return self._U

    @U.setter
    def U(self, value: np.ndarray) -> None:
        self._U = value

    @property
    def d(self) -> np.ndarray:
        if not self._ud_synced:
            self._factor()
        return self._d

    @d.setter
    def d(self, value: np.ndarray) -> None:
        self._d = value

    def _factor(self) -> None:
        """U, d ← UD factors of P (for readers outside the overridden methods)."""
        self._ud_synced = True
        if ud.factor_ud(self.P, self._U, self._d) != OK:
            self._U[:, :] = np.nan
            self._d[:] = np.nan

    def _from_ud(self) -> None:
        """P ← U diag(d) Uᵀ after code that wrote the factors (cold start, checkpoint restore)."""
        if self.P.shape != (self.ns, self.ns):
            self.P = np.empty((self.ns, self.ns))
        ud.ud_to_cov(self._U, self._d, self.P)
        self._ud_synced = True

    def _dirty(self, status: int = OK) -> None:
        self._ud_synced = False
        self._check(status)

    # ---------------------------------------------------------- starts, bumps, restore
    def cold_start(self) -> None:
        super().cold_start()  # writes U = I, d = (1, 1, 1, p0): P ← diag
        self._from_ud()

    def set_state(self, state: dict[str, Any]) -> None:
        super().set_state(state)
        self._from_ud()

    # ---------------------------------------------------------- covariance primitives
    def _cov_reset_attitude(self, P0) -> None:
        self._dirty(dense_reset_leading(self.P, 3, np.asarray(P0, float)))

    def _cov_add_diagonal(self, idx, c) -> None:
        self._dirty(dense_add_diagonal(self.P, idx, c))

    def _cov_scale(self, s) -> None:
        self.P *= np.outer(s, s)
        self._dirty()

    def _cov_close_window(self, noise_var: float) -> float:
        n = self.n_gyro
        kappa = self._regressor_reliability(self.th_acc, self.Phi_ap[:, :5 * n], noise_var)
        if kappa < 1.0:
            self._scale_regressor_columns(self.Phi_ap, kappa)
        self._dirty(dense_time_update(self.P, 3, self.Phi_aa, self.Phi_ap, self.Q_aa, self._T))
        # the parameter noise accumulated and added once a second, as radical_rt.kernels.timeupdate
        self.q_dt += self.q_params * self.acc_f[0]
        self.acc_f[ACC_NOISE_T] += self.acc_f[0]
        if self.acc_f[ACC_NOISE_T] >= NOISE_PERIOD_S:
            self._cov_add_diagonal(self.param_idx, self.q_dt.copy())
            self.q_dt[:] = 0.0
            self.acc_f[ACC_NOISE_T] = 0.0
        self._reset_time_window()
        return kappa

    def _cov_converged(self) -> bool:
        return bool((np.diag(self.P)[3:] <= self.conv_var).all())

    def _regressor_reliability(self, theta, Phi_g, noise_var: float) -> float:
        """κ of :meth:`Engine._regressor_reliability`, computed from the dense P."""
        th2 = float(theta @ theta)
        if th2 <= 0.0:
            return 0.0
        sl = slice(3, 3 + 5 * self.n_gyro)
        v = Phi_g.T @ theta
        s_par = (float(v @ self.P[sl, sl] @ v) + noise_var * float(theta @ self.Minv @ theta)) / th2
        return max(0.0, 1.0 - self.si.regressor_k_sigma ** 2 * s_par / th2)

    # ---------------------------------------------------------- measurement update
    def _vector_update(self, kind: str, H, z, rdiag, gate: float, consider=None) -> bool:
        m = H.shape[0]
        status, nis, edited = dense_gated_update(
            self.P, self.dx, H, z, rdiag, gate, self.si.edit_enabled,
            self._no_consider if consider is None else consider, self.Sbuf[:m, :m],
            self.innov[:m], self.sig[:m], self._PHt[:, :m], self._b, self._k)
        if not edited:
            self._dirty(status)
        self.diag_last[kind] = (self.innov[:m].copy(), self.sig[:m].copy(), float(nis))
        if edited:
            self.counters[f"{kind}_edited"] += 1
            return False
        self.counters[f"{kind}_used"] += 1
        self.nis_sum[kind] += nis
        return True

    # ---------------------------------------------------------- outputs, health
    def variances(self) -> np.ndarray:
        return np.diag(self.P).copy()

    def contract_params(self) -> tuple[np.ndarray, np.ndarray]:
        xc, J = contract_from_internal(self.xp, self.n_gyro)
        return xc, J @ self.P[3:, 3:] @ J.T

    def contract_sigma(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.contract_params()[1]), 0.0))

    def output_numbers(self) -> dict[str, Any]:  # (from P, not from the compiled UD call)
        return {"est": self.estimates(), "sigma": self.sigmas(), "att_sigma": self.att_sigma(),
                "latency": self.latency_estimate()}

    def _numeric(self, why: str) -> None:
        self.flags |= Flag.NUMERIC
        self.counters["numeric_faults"] += 1
        self.last_numeric = why
        dP = np.diag(self.P)
        if not (np.all(np.isfinite(self.P)) and np.all(dP > 0) and np.all(np.isfinite(self.xp))):
            self.xp[:] = np.where(np.isfinite(self.xp), self.xp, 0.0)
            self.P[:, :] = np.diag(np.concatenate([np.ones(3), np.asarray(self.si.p0_params)]))
            self._ud_synced = False
            self._begin_attitude_init()


# ------------------------------------------------------------------------------ stream helpers


def make_processor(engine_cls=Engine, table=None, clock_mode: str = "reconstruct"):
    """A stream processor as :func:`radical_rt.apps.batch.make_processor` builds it, with the engine
    class of choice (``Engine`` or :class:`DenseEngine`)."""
    from radical_rt.clock.siru_clock import ClockConfig, SiruClock
    from radical_rt.contract.params import ParamTable
    from radical_rt.stream.processor import StreamProcessor

    table = table or ParamTable()
    return StreamProcessor(table, SiruClock(ClockConfig(mode=clock_mode), n_gyro=table.n_gyro),
                           engine_type=engine_cls)


def run_archive(sp, path: str | Path):
    """Feed one archive's inputs through ``sp`` (the batch shell's loop, no output archive)."""
    from radical_rt.apps.batch import INPUTS
    from radical_rt.io.archive import ArchiveReader

    with ArchiveReader(str(path)) as reader:
        for topic, _, data in reader.iter_raw(topics=list(INPUTS)):
            sp.feed(topic[1:], data)
    sp.end_stream(None)
    return sp


def compare(a: Engine, b: Engine) -> dict[str, float]:
    """Largest differences between two engines' final states: parameters in units of the first
    engine's σ, attitude (rad), relative σ and covariance differences."""
    sa, sb = np.sqrt(a.variances()), np.sqrt(b.variances())
    Pa = np.empty((a.ns, a.ns))
    ud.ud_to_cov(a.U, a.d, Pa)
    Pb = b.P if isinstance(b, DenseEngine) else np.empty((b.ns, b.ns))
    if not isinstance(b, DenseEngine):
        ud.ud_to_cov(b.U, b.d, Pb)
    corr = np.outer(sa, sa)
    dq = a.q * np.sign(a.q[3]) - b.q * np.sign(b.q[3])
    return {"max_param_diff_sigma": float(np.max(np.abs(a.xp - b.xp) / sa[3:])),
            "att_diff_rad": float(2.0 * np.linalg.norm(dq[:3])),
            "max_sigma_rel_diff": float(np.max(np.abs(sb / sa - 1.0))),
            "max_cov_diff_corr": float(np.max(np.abs(Pa - Pb) / corr))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args(argv)
    from replayer.synth.api import synthesize

    with tempfile.TemporaryDirectory() as tmp:
        toml = Path(tmp) / "s.toml"
        toml.write_text('base = "2006216"\nt_start_s = 1000.0\n')
        sim = Path(tmp) / "sim.mcap"
        synthesize(str(toml), sim, seed=a.seed, duration=a.duration)
        out = {}
        for cls in (Engine, DenseEngine):
            t0 = time.perf_counter()
            out[cls.__name__] = run_archive(make_processor(cls), sim).engine
            print(f"{cls.__name__}: {time.perf_counter() - t0:.2f} s", file=sys.stderr)
    for k, v in compare(out["Engine"], out["DenseEngine"]).items():
        print(f"{k}: {v:.3e}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
