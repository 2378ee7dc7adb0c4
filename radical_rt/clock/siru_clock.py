"""Online SIRU clock reconstruction and repeat/miss repair (CONTRACT §1.5, notes §13).

The SIRU samples on its own oscillator; the bus reads the latest completed sample at its own
100 Hz ticks and tags it with a bus time (the read's instant, or its bus cycle's tick with the read
an unknown offset earlier), so the tag is late by a 0–10 ms sawtooth and reads near each sawtooth
wrap repeat or skip samples. :class:`SiruClock` turns the stream of
reads into the stream of distinct samples the filter needs: repeats dropped, misses bridged (or a
gap declared), each sample given its reconstructed true time ``t`` on the bus time line and its
true interval ``dt``.

Time reconstruction (``mode="reconstruct"``) estimates the line ``t_k = a + b k`` over the
unwrapped sample index k twice. Coarsely, every read of sample k at bus time τ says ``t_k <= τ``
and ``t_{k+1} > τ`` (within a margin wide enough for read jitter), half-planes whose intersection
is a convex polygon (:mod:`radical_rt.clock.clock_timing`): a band of width T until the sawtooth first
wraps. Finely, each sawtooth wrap's spate of repeats and misses is located by counting
(:mod:`radical_rt.clock.clock_line`), and a Kalman filter fits the line through these crossings, with
an honest σ; it is the line in use from the first crossing on. A constant read offset before the
tag is not observable and stays in the line (the engine's latency state takes it).
``mode="naive"`` tags each sample with the bus time of its first read (the baseline). Method and
measured accuracy: docs/clock.md.

The per-read loop is one Numba kernel (:mod:`radical_rt.clock.clock_kernels`); this class holds its
small state arrays, so the output does not depend on how the reads are split into :meth:`push`
calls, and :meth:`get_state` / :meth:`set_state` checkpoint everything. Its settings,
:class:`ClockConfig`, are in :mod:`radical_rt.clock.clock_config`.
"""

from __future__ import annotations

import math
from dataclasses import asdict
from typing import NamedTuple

import numpy as np

from radical_rt.clock import clock_layout as L
from radical_rt.clock.clock_config import ClockConfig
from radical_rt.clock.clock_kernels import (
    O_BR,
    O_DT,
    O_DTH,
    O_ST,
    O_T,
    O_TT,
    O_VAR,
    clock_push_rows,
    clock_run,
)
from radical_rt.clock.clock_line import period
from radical_rt.clock.clock_timing import line_time, pending_read, tag_sigma

COUNTER_NAMES = L.COUNTER_NAMES  # counters exposed by SiruClock.counters (declared with I)
STATE_SCHEMA = "radical.clock_state/2"
_CHUNK = 16384  # reads per kernel call (bounds the reused output buffers)


class GyroBatch(NamedTuple):
    """Samples released to the filter, in order."""

    t: np.ndarray  # (m,) reconstructed true sample time on the bus time line [s]
    dt: np.ndarray  # (m,) true interval t_k - t_{k-1} [s]
    dtheta: np.ndarray  # (m, n) increments [rad]
    status: np.ndarray  # (m,) int gyro-invalid bits
    bridged: np.ndarray  # (m,) bool: synthesized for a missing sample (skip the parity update)
    var_extra: np.ndarray  # (m,) extra attitude variance per axis [rad^2] (0 if not bridged)


_compiled: set[int] = set()


def compile_kernels(n_gyro: int = 4) -> None:
    """Compile (or load from cache) the clock kernel on scratch state, once per process: done by
    the constructor, so the first packet never waits for the JIT."""
    if n_gyro in _compiled:
        return
    ist = np.zeros(L.NI, np.int64)
    fst = np.zeros(L.f_size(n_gyro))
    fst[:L.NPRM] = ClockConfig().params()
    ist[L.I_NG] = n_gyro
    out_f = np.zeros((8, O_DTH + n_gyro))
    out_i = np.zeros((8, 3), np.int64)
    clock_run(ist, fst, np.array([1.0]), np.array([0], np.int64), np.zeros((1, n_gyro)),
              np.zeros(1, np.int64), 0, True, out_f, out_i)
    q = np.zeros(8)
    clock_push_rows(ist, fst, np.array([2.0]), np.array([1], np.int64), np.zeros((1, n_gyro)),
                    np.zeros(1, np.int64), 16, out_f, out_i, 0, q, q.copy(),
                    np.zeros((8, n_gyro)), np.zeros(8, np.int64), np.zeros(8, np.bool_), q.copy(),
                    np.zeros(8, np.int64))
    _compiled.add(n_gyro)


class SiruClock:
    """Streaming SIRU read → sample converter with clock reconstruction (see module docstring)."""

    def __init__(self, config: ClockConfig | None = None, n_gyro: int = 4) -> None:
        self.config = config if config is not None else ClockConfig()
        self.config.validate()
        self.n_gyro = int(n_gyro)
        if self.n_gyro < 1:
            raise ValueError("n_gyro must be >= 1")
        self._I = np.zeros(L.NI, np.int64)
        self._F = np.zeros(L.f_size(self.n_gyro))
        self._F[:L.NPRM] = self.config.params()
        compile_kernels(self.n_gyro)
        self._I[L.I_NG] = self.n_gyro
        self._of = np.empty((0, O_DTH + self.n_gyro))
        self._oi = np.empty((0, 3), np.int64)
        self._I[L.I_K_A] = -1
        self._F[L.F_ANOM_UNTIL] = -math.inf
        self._F[L.F_TAU_NOW] = -math.inf
        self._F[L.F_Y_LO] = self._F[L.P_Y_LO]
        self._F[L.F_Y_HI] = self._F[L.P_Y_HI]
        self._F[L.F_DELTA] = self._F[L.P_DELTA]
        self._F[L.F_T_LOCK] = -math.inf

    # ------------------------------------------------------------------ streaming
    def push(self, t_bus, tt, dtheta, status) -> GyroBatch:
        """Process one ``siru`` message's columns (k reads, in read order)."""
        return self._run(t_bus, tt, dtheta, status, final=False)

    def prepare(self, k: int, queue) -> tuple:
        """Before a compiled intake of k reads that appends to ``queue`` (a
        :class:`radical_rt.engine.gyro_queue.GyroQueue`; :class:`radical_rt.stream.siru_wire.SiruWire` runs it):
        output buffers, queue rows and tag slots for the samples k reads can release. Returns the
        clock's arguments of those kernels: (I, F, chunk, out_f, out_i, tags)."""
        self._out_room(k)
        bound = k * (int(self.config.max_bridge) + 1)
        queue.reserve(bound)
        if self._tags.shape[0] < bound:
            self._tags = np.empty(bound + bound // 4, np.int64)
        return self._I, self._F, _CHUNK, self._of, self._oi, self._tags

    def taken(self, queue, m: int) -> None:
        """After a compiled intake that succeeded: its m samples are in the queue (a refused
        message changed nothing, and this is not called)."""
        queue.end += m
        self.took(m)

    def _changed(self) -> None:
        """The state changed (a compiled intake, flush, reset, restore): drop what is cached
        from it (:attr:`tag_error_sigma_s`, :attr:`anomaly`, :attr:`counters`)."""
        self._sig_cache = self._anom_cache = self._counters_cache = None

    def took(self, m: int) -> None:
        """After a compiled intake changed the clock's state and released m samples (the queue's
        owner has counted them)."""
        self._changed()
        self._n_tags = m

    _tags = np.empty(0, np.int64)
    _n_tags = 0

    @property
    def last_tt(self) -> np.ndarray:
        """Time tags (k,) int64 of the samples the last push released (−1 for bridged ones); a
        diagnostic."""
        return self._tags[:self._n_tags].copy()

    def _out_room(self, k: int) -> None:
        """Output buffers (reused between calls) large enough for one chunk of k reads."""
        need = min(k, _CHUNK) + 2 + int(self.config.max_bridge)
        if self._of.shape[0] < need:
            self._of = np.empty((need + need // 4, O_DTH + self.n_gyro))
            self._oi = np.empty((need + need // 4, 3), np.int64)

    def flush(self) -> GyroBatch:
        """End of stream: release the read held back for look-ahead."""
        return self._run([], [], np.zeros((0, self.n_gyro)), [], final=True)

    def reset(self) -> None:
        """Stream discontinuity: forget the sequence and the phase, keep the frequency range and
        the counters. A held-back read is dropped (call :meth:`flush` first to keep it)."""
        self._changed()
        ist, fst = self._I, self._F
        ist[L.I_HAVE_A] = 0
        ist[L.I_HAVE_P] = 0
        ist[L.I_ACQ] = 0
        ist[L.I_HAVE_OUT] = 0
        ist[L.I_CONSEC_REJ] = 0
        # keep the slope range, widened for drift during the unknown pause
        dy = self.config.reset_freq_margin_ppm * 1e-6 * fst[L.P_T] * fst[L.P_NS]
        fst[L.F_Y_LO] = max(fst[L.F_Y_LO] - dy, fst[L.P_Y_LO])
        fst[L.F_Y_HI] = min(fst[L.F_Y_HI] + dy, fst[L.P_Y_HI])
        if ist[L.I_KMEM]:  # the fine line keeps its frequency too, as uncertain as the range
            fst[L.F_KCYY] += dy * dy / 3.0

    def _run(self, t_bus, tt, dtheta, status, final: bool) -> GyroBatch:
        self._changed()
        t_bus = np.ascontiguousarray(t_bus, dtype=np.float64).reshape(-1)
        tt = np.ascontiguousarray(tt, dtype=np.int64).reshape(-1)
        k = t_bus.shape[0]
        dth = np.ascontiguousarray(dtheta, dtype=np.float64).reshape(k, self.n_gyro)
        st = np.ascontiguousarray(status, dtype=np.int64).reshape(-1)
        if tt.shape[0] != k or st.shape[0] != k:
            raise ValueError("t_bus, tt, dtheta and status must have the same length")
        self._out_room(k)
        parts_f, parts_i = [], []
        j, end = 0, k + 1 if final else k
        while j < end:  # bounded chunks; the kernel stops early if its output could overflow
            stop = min(j + _CHUNK, k)
            last = final and stop == k
            m, j = clock_run(self._I, self._F, t_bus[:stop], tt[:stop], dth[:stop], st[:stop], j,
                             last, self._of, self._oi)
            parts_f.append(self._of[:m].copy())
            parts_i.append(self._oi[:m].copy())
        if not parts_f:
            of, oi = self._of[:0].copy(), self._oi[:0].copy()
        elif len(parts_f) == 1:
            of, oi = parts_f[0], parts_i[0]
        else:
            of, oi = np.concatenate(parts_f), np.concatenate(parts_i)
        self._tags, self._n_tags = oi[:, O_TT].copy(), oi.shape[0]
        return GyroBatch(of[:, O_T], of[:, O_DT], of[:, O_DTH:], oi[:, O_ST],
                         oi[:, O_BR].astype(bool), of[:, O_VAR])

    def pending_view(self) -> tuple[bool, int, float, np.ndarray]:
        """(has, status, period_s, dtheta view): :meth:`pending` and :meth:`period_s` in one call,
        the increments as a view of the clock state (valid until the next push; read only)."""
        has, status, per = pending_read(self._I, self._F)
        dp = L.DA + self.n_gyro
        return has, status, per, self._F[dp:dp + self.n_gyro]

    def state_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """The clock's state arrays (int I, float F; layout :mod:`radical_rt.clock.clock_layout`) for
        kernels that read it (:func:`radical_rt.engine.gyro_queue.predict_pending`); read only."""
        return self._I, self._F

    def pending(self) -> tuple[np.ndarray, int] | None:
        """The read held back for look-ahead when it is probably the next sample (its tag differs
        from the last accepted one): ``(dtheta (n,) rad, status bits)``; None otherwise. For
        low-latency predictions only: whether it is a repeat, a miss or the next sample is known
        when the following read arrives."""
        has, status, _period, dtheta = self.pending_view()
        return (dtheta.copy(), status) if has else None

    def period_s(self) -> float:
        """Current estimate of the SIRU sample period [s]."""
        return float(period(self._F))

    # ------------------------------------------------------------------ status
    @property
    def counters(self) -> dict[str, int]:
        """Cumulative counters (CONTRACT §5 meanings for samples, repeated, missing); cached until
        the state changes."""
        c = self._counters_cache
        if c is None:
            c = dict(zip(COUNTER_NAMES, self._I[L.C0:L.C0 + len(COUNTER_NAMES)].tolist(),
                         strict=True))
            c["tag_wraps"] = int(self._I[L.I_NET_HI] - self._I[L.I_NET_LO])
            self._counters_cache = c
        return dict(c)  # (a copy: the caller may keep it)

    _counters_cache: dict[str, int] | None = None

    @property
    def anomaly(self) -> bool:
        """CLOCK_ANOMALY: raised for ``anomaly_hold_s`` of bus time after each anomaly event
        (cached like :attr:`tag_error_sigma_s`; read with every flags evaluation)."""
        a = self._anom_cache
        if a is None:
            a = self._anom_cache = bool(self._F[L.F_TAU_NOW] < self._F[L.F_ANOM_UNTIL])
        return a

    _anom_cache: bool | None = None

    @property
    def locked(self) -> bool:
        """The sample-time line is known to better than ``lock_sigma_s``."""
        return bool(self._I[L.I_ACQ]) and self.tag_error_sigma_s < self.config.lock_sigma_s

    @property
    def tag_error_sigma_s(self) -> float:
        """1σ uncertainty of the reconstructed time of the latest sample [s] (cached until the
        state changes: push, flush, reset, set_state)."""
        sig = self._sig_cache
        if sig is None:
            sig = self._sig_cache = float(tag_sigma(self._I, self._F))
        return sig

    _sig_cache: float | None = None

    def freq_offset_ppm(self) -> float:
        """Estimated SIRU sample-period offset ε (T_siru = T (1 + ε)) [ppm]."""
        return float(self._F[L.F_CY] / self._F[L.P_NS] / self._F[L.P_T] * 1e6)

    def status(self) -> tuple[str, str]:
        """``(state, note)``: ``naive``; ``acquiring`` (no sawtooth wrap seen since the phase
        started: the sample phase is known only within the 0–10 ms band); ``one_wrap`` (phase
        known, frequency not yet: locks at the next wrap); ``locked``; ``unlocked`` (the line's σ
        grew above the lock threshold). The note says why, in words, for operators."""
        if self.config.mode == "naive":
            return "naive", "naive time tags (the bus tag of each sample's first read)"
        if self.locked:
            return "locked", ""
        ist, fst = self._I, self._F
        sig_us = self.tag_error_sigma_s * 1e6
        if not ist[L.I_KAL]:
            span = fst[L.F_TAU_NOW] - fst[L.F_GRID0] if ist[L.I_GRID] else 0.0
            bound = f"; so |ε| < {self.config.period_s / span * 1e6:.0f} ppm" if span > 1.0 else ""
            return "acquiring", (f"no sawtooth wrap in {span:.0f} s of reads{bound}: the sample "
                                 f"phase is known within the 10 ms band only (σ {sig_us:.0f} µs)")
        if ist[L.I_NCROSS] < 2:
            return "one_wrap", ("one sawtooth wrap: phase known, frequency not yet (σ "
                                f"{sig_us:.0f} µs, growing); locks at the next wrap")
        return "unlocked", (f"time-line σ {sig_us:.0f} µs above the lock threshold "
                            f"{self.config.lock_sigma_s * 1e6:.0f} µs")

    def telemetry(self) -> dict:
        """Clock estimates and counters (msgpack-able)."""
        acq = bool(self._I[L.I_ACQ])
        k = int(self._I[L.I_K_A])
        y_lo, y_hi = self._F[L.F_Y_LO], self._F[L.F_Y_HI]
        scale = 1e6 / self._F[L.P_NS] / self._F[L.P_T]
        state, note = self.status()
        t_lock = float(self._F[L.F_T_LOCK])
        return {
            "mode": self.config.mode,
            "state": state,
            "note": note,
            "t_first_lock_s": t_lock if math.isfinite(t_lock) else None,
            "locked": self.locked,
            "anomaly": self.anomaly,
            "freq_offset_ppm": self.freq_offset_ppm() if acq else self.config.freq_offset_ppm,
            "freq_offset_range_ppm": [float(y_lo * scale), float(y_hi * scale)],
            "period_s": float(period(self._F)),
            "offset_s": float(self._F[L.F_E_LAST]) if acq else None,
            "t_last_sample_s": float(line_time(self._I, self._F, k)) if acq
            else None,
            "tag_error_sigma_s": self.tag_error_sigma_s,
            "max_rejected_violation_s": float(self._F[L.F_MAX_VIOL]),
            "jitter_margin_s": float(self._F[L.F_DELTA]),
            "polygon_vertices": int(self._I[L.I_NV]),
            "fine_line": bool(self._I[L.I_KAL]),
            "freq_offset_sigma_ppm": (float(math.sqrt(max(self._F[L.F_KCYY], 0.0)) * scale)
                                      if self._I[L.I_KMEM] else None),
            "read_jitter_s": float(self._F[L.F_SIG_READ]),
            "counters": self.counters,
        }

    # ------------------------------------------------------------------ checkpoint
    def get_state(self) -> dict:
        """Everything needed to continue bit-identically (msgpack-able)."""
        return {
            "schema": STATE_SCHEMA,
            "config": asdict(self.config),
            "n_gyro": self.n_gyro,
            "I": [int(v) for v in self._I],
            "F": [float(v) for v in self._F],
        }

    def set_state(self, state: dict) -> None:
        """Restore a :meth:`get_state` checkpoint (configuration included)."""
        self._changed()
        if state.get("schema") != STATE_SCHEMA:
            raise ValueError(f"unknown clock state schema {state.get('schema')!r}")
        config = ClockConfig(**state["config"])
        n_gyro = int(state["n_gyro"])
        ist = np.asarray(state["I"], np.int64)
        fst = np.asarray(state["F"], np.float64)
        if ist.shape != (L.NI,) or fst.shape != (L.f_size(n_gyro),):
            raise ValueError("clock state arrays have the wrong size")
        fresh = SiruClock(config, n_gyro)
        fresh._I[:] = ist
        fresh._F[:] = fst
        self.__dict__.update(fresh.__dict__)
