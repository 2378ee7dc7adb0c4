"""Engine state arrays, health bookkeeping, snapshots and checkpoints (no filter math here).

:class:`EngineState` owns every array the engine works on (allocated once), the counters, flags and
mode, and turns them into output snapshots (SI) and msgpack-able checkpoints. The scalar state
(time, mode, flags, attitude valid, lock latch) lives in the ``io`` and ``cnt`` arrays of the
compiled calls (:mod:`radical_rt.engine.loop_layout`); the attributes are views of them.
"""

from __future__ import annotations

import math
from collections import defaultdict
from types import SimpleNamespace
from typing import Any

import numpy as np

from radical_rt.contract.flags import Flag
from radical_rt.contract.geometry import Geometry
from radical_rt.contract.state import PARAM_GROUPS, StateLayout
from radical_rt.engine.engine_layout import SLOTS, slot_problems
from radical_rt.engine.loop_layout import (
    CNT,
    CNT_FLAGS,
    CNT_MASKED,
    CNT_PAR_STAT,
    CNT_PAR_SUMS,
    IO,
    IO_ATT_VALID,
    IO_LOCKED_SINCE,
    IO_MODE,
    IO_PAR_NU,
    IO_PAR_RHO,
    IO_PAR_T0,
    IO_PAR_Z,
    IO_T,
)
from radical_rt.engine.steps import MODE_CONVERGED, MODE_CONVERGING, MODE_DEGRADED, MODE_INIT
from radical_rt.kernels import ud
from radical_rt.kernels.parametrization import (
    contract_from_internal,
    contract_sigma_ud,
    contract_values,
)

#: the mode names and their codes in io (IO_MODE)
MODE_CODE = {"init": MODE_INIT, "converging": MODE_CONVERGING, "converged": MODE_CONVERGED,
             "degraded": MODE_DEGRADED}
MODE_NAME = {v: k for k, v in MODE_CODE.items()}


def _io_float(index: int, doc: str) -> property:
    """A float of the engine's io array (loop_layout.IO) as an attribute."""
    return property(lambda self: self._io.item(index),
                    lambda self, v: self._io.__setitem__(index, v), doc=doc)


def _drained(name: str, doc: str) -> property:
    """A bookkeeping attribute stored as ``_b_<name>``, read and replaced after
    :meth:`EngineState._drain`."""
    attr = "_b_" + name

    def get(self):
        if self._undrained:
            self._drain()
        return getattr(self, attr)

    def put(self, value) -> None:
        if self._undrained:
            self._drain()
        setattr(self, attr, value)

    return property(get, put, doc=doc)


class EngineState:
    """Arrays and bookkeeping of the engine for a given state layout and geometry."""

    def __init__(self, layout: StateLayout, geometry: Geometry) -> None:
        self.layout, self.geo = layout, geometry
        #: (group, slice of xp) per parameter group, for the per-group outputs
        self._group_slices = [(g, param_slice(layout, g)) for g in PARAM_GROUPS]
        n = self.n_gyro = geometry.n_gyro
        ns = self.ns = layout.n_states
        npar, nr = ns - 3, n - 3
        self.q = np.array([0.0, 0.0, 0.0, 1.0])  # q_body_from_inertial
        self.xp = np.zeros(npar)  # parameters, state order (SI)
        self.U, self.d, self.dx = np.eye(ns), np.ones(ns), np.zeros(ns)
        self.h, self.r3 = np.zeros(ns), np.zeros(3)
        self.H_att, self.H_phi = np.zeros((3, 3)), np.zeros((3, 3))
        self.A = np.zeros((3, n))  # estimated scaled sense axes (internal parametrization)
        self.Minv, self.Gp, self.N = np.eye(3), np.zeros((3, n)), geometry.N.copy()
        self.Phi_aa, self.Phi_ap, self.Q_aa = np.eye(3), np.zeros((3, npar)), np.zeros((3, 3))
        self.z_par, self.H_par = np.zeros(nr), np.zeros((nr, npar))  # parity measurement buffers
        self.par_y, self.par_t = np.zeros((2, n)), np.zeros((2, n))  # parity-sum statistics
        self.theta_par, self.Phi_par = np.zeros(3), np.zeros((3, 5 * n))
        # closed parity sums waiting for their lag: a ring of rows (t, noise, par_y, par_t)
        # (see parity_queue), head and count in pq_i; grown by the engine's params_changed
        self.pq, self.pq_i = np.zeros((16, 2 + 4 * n)), np.zeros(2, np.int64)
        self.par_innov, self.par_sig = np.zeros(nr), np.zeros(nr)  # last parity update
        self.p0 = np.zeros(npar)  # initial parameter variances (numeric-fault reset) [unit²]
        # the FDI statistic of a queued parity sum (its own buffers: z (1,), H (1, npar), θ, Φ, h)
        self.fdi_z, self.fdi_H = np.zeros(1), np.zeros((1, npar))
        self.fdi_th, self.fdi_Phi, self.fdi_h = np.zeros(3), np.zeros((3, 5 * n)), np.zeros(ns)
        # acc_f: window length, parity-sum noise and length, time since the parameter noise was
        # last added (timeupdate.ACC_NOISE_T) [s]
        self.acc_i, self.acc_f = np.zeros(4, np.int64), np.zeros(4)
        self.th_acc = np.zeros(3)  # Σθ̂ over the time-update window
        self.q_dt = np.zeros(npar)  # parameter process noise accumulated, not yet added [unit²]
        self.kappa_last = np.ones(2)  # last regressor reliability (time update, parity)
        self.omega = np.zeros(3)
        m_max = max(3, nr)  # measurement rows per update (tracker 3, parity n−3)
        self.Hbuf, self.Fbuf = np.zeros((m_max, ns)), np.zeros((m_max, ns))
        self.Sbuf, self.innov, self.sig = np.zeros((m_max, m_max)), np.zeros(m_max), np.zeros(m_max)
        self.Hwbuf, self.zwbuf, self.Lbuf = np.zeros((m_max, ns)), np.zeros(m_max), np.zeros((m_max, m_max))
        self.ws = ud.UDWorkspace(ns)
        # the propagation's work arrays (radical_rt.kernels.propagate.SampleWork, same names)
        self.pw = SimpleNamespace(
            c=np.zeros(n), sg=np.zeros(n), s=np.zeros(n), gh=np.zeros(n), th=np.zeros(3),
            F=np.zeros((3, 5)), work4=np.zeros(4), dq=np.zeros(4), active=np.zeros(n, np.bool_),
            R=np.zeros((3, 3)), T=np.zeros((3, 3)), Gm=np.zeros((3, n)), Mm=np.zeros((3, 3)))
        self.param_idx = np.arange(3, ns, dtype=np.int64)
        self.gyro_mask = np.zeros(ns, dtype=np.bool_)  # the gyro calibration states (b … dv)
        self.gyro_mask[layout.gyro_params] = True
        self.scale_mask = self.gyro_mask.copy()  # λ, μ, du, dv (the gyro calibration but b)
        self.scale_mask[layout["b"]] = False
        self.excluded = np.zeros(n, dtype=np.bool_)
        # the scalar state: kept in the arrays of the compiled calls (radical_rt.engine.
        # loop_layout); t, mode, flags, att_valid, locked_since are views of them
        self._io, self._cnt = np.zeros(IO.end), np.zeros(CNT.end, np.int64)
        self._cnt[CNT_MASKED] = -1
        self.flags = int(Flag.NOT_CONVERGED)
        self.mode = "init"
        self.t = -math.inf
        self.att_valid = False
        self.masked = False
        self.counters: dict[str, int] = defaultdict(int)
        self.nis_sum: dict[str, float] = defaultdict(float)
        #: per measurement kind, [updates used, their NIS sum] while the time line was locked
        #: (σ_t ≤ timing_consider_s): the NIS statistics of the calibrating updates (not saved in
        #: checkpoints)
        self.nis_locked: dict[str, list] = {k: [0, 0.0] for k in ("st1", "st2", "parity")}
        self.diag_last: dict[str, tuple] = {}
        self.last_valid_st: dict[int, float] = {}
        self.last_numeric = ""
        self.conv_var = np.full(ns - 3, np.inf)  # convergence thresholds², set from the table
        self.q_params = np.zeros(npar)  # parameter process noise [unit²/s], set from the table
        self.st_sigma = np.zeros(3)  # tracker noise 1σ at st_ref_stars [rad], set from the table
        self.locked_since = math.inf  # start of the current locked run of the time line [s]
        self._sum_pending = None  # the FDI statistic of a parity sum queued since the last hook

    # ---------------------------------------------------------------- scalar state
    # Views of io and cnt, where the compiled calls keep them: always current.
    t = _io_float(IO_T, "Engine time: the newest event given to the filter [s] (−inf: none yet).")
    locked_since = _io_float(IO_LOCKED_SINCE, "Start of the current locked run of the time line "
                                              "[s] (inf: not locked).")

    @property
    def att_valid(self) -> bool:
        """Whether the attitude is initialized."""
        return self._io.item(IO_ATT_VALID) != 0.0

    @att_valid.setter
    def att_valid(self, v: bool) -> None:
        self._io[IO_ATT_VALID] = 1.0 if v else 0.0

    @property
    def mode(self) -> str:
        """init | converging | converged | degraded."""
        return MODE_NAME[self._io.item(IO_MODE)]

    @mode.setter
    def mode(self, v: str) -> None:
        self._io[IO_MODE] = MODE_CODE[v]

    @property
    def flags(self) -> int:
        """The engine's flags (CONTRACT §4 bits)."""
        return self._cnt.item(CNT_FLAGS)

    @flags.setter
    def flags(self, v: int) -> None:
        self._cnt[CNT_FLAGS] = int(v)

    # The bookkeeping maps: Python objects, brought up to date with what the compiled calls
    # counted since Python last looked (the shell's _drain) whenever they are read or replaced.
    _undrained = False  # the compiled calls have counted something Python has not taken yet

    def _drain(self) -> None:
        """Take what the compiled calls counted into the bookkeeping (the shell's)."""
        self._undrained = False

    counters = _drained("counters", "event counters {name: count}")
    nis_sum = _drained("nis_sum", "sum of the NIS of the used updates per kind (st1, st2, "
                                  "parity)")
    nis_locked = _drained("nis_locked", "per kind, [updates used, their NIS sum] while the time "
                                        "line was locked")
    diag_last = _drained("diag_last", "per kind, the last update's (innovation, 1σ, NIS)")
    last_valid_st = _drained("last_valid_st", "the last valid epoch [s] per tracker 1, 2 seen")
    masked = _drained("masked", "whether the last propagation masked a gyro")
    last_numeric = _drained("last_numeric", "the text of the last numeric fault ('' : none)")
    _b_sum_pending: tuple | None = None

    @property
    def _sum_pending(self):
        """The FDI statistic (ν, ρ, t0, z) of the parity sum queued since the last window hook
        (None: none; (): not computed), taken from the compiled calls' io and cnt on its own (the
        window hook reads it at every parity sum; the rest of the bookkeeping waits until read)."""
        cnt = self._cnt
        if cnt.item(CNT_PAR_SUMS):
            io = self._io
            self._b_sum_pending = ((io.item(IO_PAR_NU), io.item(IO_PAR_RHO), io.item(IO_PAR_T0),
                                    io.item(IO_PAR_Z)) if cnt.item(CNT_PAR_STAT) else ())
            cnt[CNT_PAR_SUMS] = cnt[CNT_PAR_STAT] = 0
        return self._b_sum_pending

    @_sum_pending.setter
    def _sum_pending(self, value) -> None:
        if hasattr(self, "_cnt"):
            self._sum_pending  # noqa: B018 (a sum the calls queued is replaced, not kept)
        self._b_sum_pending = value

    # ---------------------------------------------------------------- packed storage
    # the arrays the compiled release reads or writes: radical_rt.engine.engine_layout.SLOTS

    def _pack(self) -> None:
        """Move the arrays of :data:`radical_rt.engine.engine_layout.SLOTS` into three flat buffers
        (float64, int64, bool; dtype and rank checked against the table) and make the attributes
        views of them, so a compiled call receives the whole state as a few
        arrays (``_fb``, ``_ib``, ``_bb`` and the layout ``_lay``: offset, rows, columns, buffer
        per array; radical_rt.engine.engine_layout.unpack). The geometry's nominal triads are copied (the
        Geometry object keeps its own). Every array keeps its shape and is updated in place."""
        arrays = [getattr(self if s.owner == "" else getattr(self, s.owner), s.name)
                  for s in SLOTS]
        probs = [p for s, a in zip(SLOTS, arrays, strict=True) for p in slot_problems(s, a)]
        if probs:  # a programming error (an array created with another dtype or rank)
            raise TypeError("engine state does not fit radical_rt.engine.engine_layout: "
                            + "; ".join(probs))
        sizes = [0, 0, 0]
        lay = np.zeros((len(arrays), 4), np.int64)
        for i, (s, a) in enumerate(zip(SLOTS, arrays, strict=True)):
            r, c = (a.shape[0], a.shape[1]) if a.ndim == 2 else (a.shape[0], 0)
            lay[i] = sizes[s.buffer], r, c, s.buffer
            sizes[s.buffer] += a.size
        bufs = (np.zeros(sizes[0]), np.zeros(sizes[1], np.int64), np.zeros(sizes[2], np.bool_))
        self._fb, self._ib, self._bb = bufs
        self._lay = lay
        for i, (s, a) in enumerate(zip(SLOTS, arrays, strict=True)):
            o = int(lay[i, 0])
            view = bufs[s.buffer][o:o + a.size].reshape(a.shape)
            view[...] = a
            if s.owner == "geo":  # keep the Geometry untouched: the engine's own copies
                setattr(self, "_geo_" + s.name, view)
            else:
                setattr(self if s.owner == "" else getattr(self, s.owner), s.name, view)

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Copies (copy.deepcopy, pickle) copy each view on its own: put the copied arrays back
        into fresh packed buffers, and forget cached views of them."""
        self.__dict__.update(state)
        if "_lay" in state:
            self._pack()
        if "_views" in state:
            self._views: dict[int, tuple[np.ndarray, ...]] = {}

    # ---------------------------------------------------------------- outputs
    def variances(self) -> np.ndarray:
        """Diagonal of P (ns,) from the UD factors (O(n²), P not formed)."""
        ud.variances(self.U, self.d, self.ws.var)
        return self.ws.var.copy()

    def contract_params(self) -> tuple[np.ndarray, np.ndarray]:
        """Parameter estimate (npar,) and covariance (npar, npar) in the CONTRACT §1.5 parameters.

        The engine estimates internal parameters (linear scaled-axis form, :mod:`radical_rt.kernels.model`);
        this converts exactly, with the covariance mapped by the conversion's Jacobian.
        """
        xc, J = contract_from_internal(self.xp, self.n_gyro)
        P = np.empty((self.ns, self.ns))
        ud.ud_to_cov(self.U, self.d, P)
        Pp = P[3:, 3:]
        return xc, J @ Pp @ J.T

    def estimates(self) -> dict[str, list[float]]:
        """Parameter estimates per group (CONTRACT §1.5 parameters), SI."""
        return self._by_group(contract_values(self.xp, self.n_gyro, self._jacobian_work()))

    def _by_group(self, values: np.ndarray) -> dict[str, list[float]]:
        """Split a parameter vector (npar,) into {group: list} (PARAM_GROUPS order)."""
        v = values.tolist()
        return {g: v[sl] for g, sl in self._group_slices}

    def sigmas(self, var: np.ndarray | None = None) -> dict[str, list[float]]:
        """Parameter 1σ per group (CONTRACT §1.5 parameters), SI. ``var`` is ignored (kept for
        compatibility): the σ come from the full parameter covariance mapped to the contract's
        parameters."""
        return self._by_group(self.contract_sigma())

    def contract_sigma(self) -> np.ndarray:
        """1σ (npar,) of the contract's parameters: sqrt(diag(J P_pp Jᵀ)) straight from the UD
        factors, Σ_l d_l (J U_pp)²_il (P_pp = U_pp D_p U_ppᵀ because U is unit upper triangular;
        neither P nor J P Jᵀ is formed; :func:`radical_rt.kernels.parametrization.contract_sigma_ud`). The dense
        reference overrides it."""
        sig = np.empty(self.xp.shape[0])
        contract_sigma_ud(self.xp, self.n_gyro, self.U, self.d, self._jacobian_work(), sig)
        return sig

    def _jacobian_work(self) -> np.ndarray:
        """Work array (npar, npar) for the Jacobian ∂contract/∂internal of :meth:`estimates` and
        :meth:`contract_sigma` (neither reads what it holds)."""
        npar = self.xp.shape[0]
        if self._j_work is None or self._j_work.shape[0] != npar:
            self._j_work = np.zeros((npar, npar))
        return self._j_work

    _j_work: np.ndarray | None = None

    def att_sigma(self) -> list[float]:
        """Attitude 1σ, body axes [rad] (from the UD variances)."""
        return [sigma_of(v) for v in self.variances()[:3].tolist()]

    def snapshot(self) -> dict[str, Any]:
        """Everything a telemetry packet may contain (SI, plain Python types)."""
        return {
            "t": self.t, "q_body_from_inertial": self.q.tolist(), "flags": int(self.flags),
            "mode": self.mode, "omega_body": self.omega.tolist(), "est": self.estimates(),
            "sigma": self.sigmas(), "att_sigma": self.att_sigma(),
            "residuals": self.residual_stats(), "counters": dict(sorted(self.counters.items())),
            "excluded": [int(i) for i in np.nonzero(self.excluded)[0]],
        }

    def residual_stats(self) -> dict[str, Any]:
        """Last innovation, its 1σ and NIS per measurement kind, and mean NIS so far (diag_last
        holds them as arrays or lists)."""
        out: dict[str, Any] = {}
        counters, nis_sum = self.counters, self.nis_sum
        for kind, (innov, sig, nis) in self.diag_last.items():
            used = counters.get(USED_KEY.get(kind) or kind + "_used", 0)
            out[kind] = {"innov": _as_list(innov), "sigma": _as_list(sig), "nis": float(nis),
                         "nis_mean": nis_sum.get(kind, 0.0) / used if used else None}
        return out

    # ---------------------------------------------------------------- checkpoints
    _ARRAYS = ("q", "xp", "U", "d", "N", "omega", "excluded")

    def get_state(self) -> dict[str, Any]:
        """msgpack-able checkpoint of the estimates, UD factors and bookkeeping."""
        arrays = {k: {"dtype": getattr(self, k).dtype.str, "shape": list(getattr(self, k).shape),
                      "data": getattr(self, k).tobytes()} for k in self._ARRAYS}
        return {"arrays": arrays, "flags": int(self.flags), "mode": self.mode, "t": self.t,
                "att_valid": self.att_valid, "counters": dict(self.counters),
                "nis_sum": dict(self.nis_sum),
                "last_valid_st": {str(k): v for k, v in self.last_valid_st.items()}}

    def set_state(self, state: dict[str, Any]) -> None:
        """Restore a checkpoint made by :meth:`get_state` (same layout and geometry)."""
        for k in self._ARRAYS:
            a = state["arrays"][k]
            arr = np.frombuffer(a["data"], dtype=np.dtype(a["dtype"])).reshape(a["shape"])
            if arr.shape != getattr(self, k).shape:
                raise ValueError(f"checkpoint array {k} has shape {arr.shape}, "
                                 f"expected {getattr(self, k).shape}")
            getattr(self, k)[...] = arr
        self.flags, self.mode, self.t = int(state["flags"]), state["mode"], float(state["t"])
        self.att_valid = bool(state["att_valid"])
        self.counters = defaultdict(int, state["counters"])
        self.nis_sum = defaultdict(float, state["nis_sum"])
        self.last_valid_st = {int(k): v for k, v in state["last_valid_st"].items()}
        self.state_restored()

    def state_restored(self) -> None:
        """Rebuild what is derived from the restored arrays (the engine overrides this)."""


#: the counters of the used and of the edited updates per measurement kind
USED_KEY = {k: k + "_used" for k in ("st1", "st2", "parity")}
EDITED_KEY = {k: k + "_edited" for k in ("st1", "st2", "parity")}


def _as_list(x: Any) -> list:
    """``np.atleast_1d(x).tolist()``, without the NumPy call for the usual cases: a 1-D array,
    a list of floats (a copy)."""
    if type(x) is np.ndarray and x.ndim == 1:
        return x.tolist()
    if type(x) is list and all(type(v) is float for v in x):
        return list(x)
    return np.atleast_1d(x).tolist()


def sigma_of(v: float) -> float:
    """The 1σ of a variance v, ``float(np.sqrt(v))`` of a float: math.sqrt (the same correctly rounded result) where it
    is defined, NumPy's for the rest (a negative or NaN variance gives its NaN)."""
    return math.sqrt(v) if v >= 0.0 else float(np.sqrt(v))


def param_slice(layout: StateLayout, group: str) -> slice:
    """Slice of a group inside the parameter vector xp (state index − 3)."""
    s = layout[group]
    return slice(s.start - 3, s.stop - 3)
