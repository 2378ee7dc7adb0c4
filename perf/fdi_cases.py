"""The fault cases of the FDI table (:mod:`perf.fdi_table`) and of the FDI tests: scenario files
with one injected fault (:func:`fault_toml`, :func:`synth`), the fault kinds and onset
(``KINDS``, ``FAULT_T``, ``SPLIT_T``), a StreamProcessor run that records the fault messages,
attitude and parameters against truth (:class:`Run`, forkable at ``SPLIT_T``), and its figures of
merit (:func:`evaluate`: detection and isolation delays, errors in units of the engine's σ).
"""

from __future__ import annotations

import copy
import json
import math
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

FAULT_T = 2400.0  # fault onset, s from the run start (mid +360° y slew)
SPLIT_T = 2390.0  # the fault cases continue from a copy of the nominal processor at this time
DURATION = 3600.0
SEED = 1
KINDS = {  # label → [[faults]] entries besides kind/gyro/start_s
    "bias 0.5 deg/hr": {"kind": "bias_step", "bias_deg_hr": 0.5},
    "bias 5 deg/hr": {"kind": "bias_step", "bias_deg_hr": 5.0},
    "scale +1000 ppm": {"kind": "scale_jump", "lam_ppm": 1000.0},
    "zero output": {"kind": "zero"},
    "noise 0.1\"/sample": {"kind": "noise_burst", "sigma_arcsec": 0.1},
}
INPUTS = ("/siru", "/st1", "/st2", "/temp")
TRUTH = ("/truth/attitude", "/truth/params")


def fault_toml(fault: dict[str, Any] | None = None, duration: float = DURATION,
               name: str = "fdi", moves: list | None = None, t_start: float = 0.0) -> str:
    """A 2006216-based scenario, optionally with one ``[[faults]]`` table (times from the start)."""
    lines = ['base = "2006216"', f'name = "{name}"', f"duration_s = {duration!r}",
             f"t_start_s = {t_start!r}"]
    if moves:
        lines += ["[maneuver]"]
        for axis, angle, hold in moves:
            lines += ["[[maneuver.moves]]", f'axis = "{axis}"', f"angle_deg = {angle!r}",
                      f"hold_s = {hold!r}"]
    if fault:
        lines += ["[[faults]]"]
        for k, v in fault.items():
            lines.append(f"{k} = {json.dumps(v)}")
    return "\n".join(lines) + "\n"


def synth(toml_text: str, path: Path, seed: int = SEED) -> Path:
    from replayer.synth import synthesize
    toml = path.with_suffix(".toml")
    toml.write_text(toml_text)
    synthesize(str(toml), str(path), seed=seed, progress=False)
    return path


class Run:
    """A StreamProcessor fed an archive, recording the fault messages, the attitude and its σ at
    1 Hz, and the parameters with σ every ``param_period`` s; truth kept from the archive."""

    def __init__(self, param_period: float = 60.0) -> None:
        from radical_rt.apps.batch import make_processor
        self.sp = make_processor()
        self.param_period = param_period
        self.faults: list[dict[str, Any]] = []
        self.att: list[tuple[float, np.ndarray, np.ndarray]] = []
        self.params: list[tuple[float, dict, dict, list[int]]] = []
        self.truth_att: list[tuple[float, list[float]]] = []
        self.truth_par: list[dict[str, Any]] = []
        self.next_att = -math.inf
        self.next_par = -math.inf
        self.wall = 0.0

    def fork(self) -> Run:
        """An exact copy to continue with other data (the copy's engine has the copy's processor
        as its hooks: deepcopy keeps the references within the copied object graph)."""
        return copy.deepcopy(self)

    def feed(self, topic: str, data: bytes) -> None:
        if topic in TRUTH:
            msg = msgpack.unpackb(data, raw=False)
            if topic == "/truth/attitude":
                self.truth_att.append((msg["t_bus"], msg["q_body_from_inertial"]))
            else:
                self.truth_par.append(msg)
            return
        for tp, msg in self.sp.feed(topic[1:], data):
            if tp == "fault":
                self.faults.append({"t": msg["t"], "set": msg["set"], "cleared": msg["cleared"],
                                    "detail": msg["detail"]})
        e = self.sp.engine
        if e.att_valid and e.t >= self.next_att:
            var = e.variances()
            self.att.append((e.t, e.q.copy(), np.sqrt(var[:3])))
            self.next_att = e.t + 1.0
        if e.att_valid and e.t >= self.next_par:
            self.params.append((e.t, e.estimates(), e.sigmas(),
                                [int(i) for i in np.nonzero(e.excluded)[0]]))
            self.next_par = e.t + self.param_period

    def feed_archive(self, path: Path, t_from: float = -math.inf, t_to: float = math.inf,
                     prefix_hash: Any = None, progress=None, progress_every_s: float = 3600.0) -> None:
        """Feed the messages with t_from ≤ log time < t_to (s from the bus origin); the ones before
        t_from only update ``prefix_hash`` (hashlib object) when given. ``progress(t)`` is called
        every ``progress_every_s`` of log time."""
        from radical_rt.io.archive import ArchiveReader
        t0 = time.perf_counter()
        lo, hi = t_from * 1e9, t_to * 1e9
        next_p = -math.inf
        with ArchiveReader(str(path)) as reader:
            for topic, log_ns, data in reader.iter_raw(topics=[*INPUTS, *TRUTH]):
                if log_ns < lo:
                    if prefix_hash is not None:
                        prefix_hash.update(topic.encode() + log_ns.to_bytes(8, "little") + data)
                    continue
                if log_ns >= hi:
                    break
                self.feed(topic, data)
                if progress is not None and log_ns >= next_p:
                    if next_p > -math.inf:
                        progress(log_ns * 1e-9)
                    next_p = log_ns + progress_every_s * 1e9
        self.wall += time.perf_counter() - t0

    def finish(self) -> None:
        self.sp.end_stream(None)


def _slerp_truth(truth_att, times):
    from scipy.spatial.transform import Rotation, Slerp
    tt = np.array([t for t, _ in truth_att])
    rots = Rotation.from_quat(np.array([q for _, q in truth_att]))
    times = np.clip(times, tt[0], tt[-1])
    return Slerp(tt, rots)(times)


def evaluate(run: Run, t_fault: float | None) -> dict[str, Any]:
    """Detection, isolation and post-isolation consistency of one run (times in s of bus time)."""
    from scipy.spatial.transform import Rotation

    from radical_rt.contract.state import PARAM_GROUPS
    e = run.sp.engine
    fdi = e.fdi
    out: dict[str, Any] = {"alarms": [dict(a) for a in fdi.alarms],
                           "isolations": [{k: v for k, v in r.items() if k != "bank"}
                                          for r in fdi.isolations],
                           "counts": dict(fdi.counts), "state": fdi.state,
                           "excluded": [int(i) for i in np.nonzero(e.excluded)[0]],
                           "wall_s": run.wall}
    if t_fault is not None:
        first = fdi.alarms[0] if fdi.alarms else None
        out["detect_delay_s"] = first["t_alarm"] - t_fault if first else None
        iso = fdi.isolations[0] if fdi.isolations else None
        out["isolated_gyro"] = iso["gyro"] if iso else None
        out["isolate_delay_s"] = iso["t_isolated"] - t_fault if iso else None
    t_iso = fdi.isolations[0]["t_isolated"] if fdi.isolations else None
    # attitude error / σ (body axes) at 1 Hz, after the isolation (or the whole run if none)
    t = np.array([a[0] for a in run.att])
    sel = t > (t_iso + 1.0 if t_iso is not None else -math.inf)
    if sel.any() and run.truth_att:
        R_true = _slerp_truth(run.truth_att, t[sel])
        q_est = np.array([a[1] for a, s in zip(run.att, sel, strict=True) if s])
        sig = np.array([a[2] for a, s in zip(run.att, sel, strict=True) if s])
        err = (Rotation.from_quat(q_est) * R_true.inv()).as_rotvec()  # R_est R_trueᵀ = R(δθ)
        z = err / sig
        out["att"] = {"n": int(z.shape[0]), "max_abs_z": float(np.max(np.abs(z))),
                      "frac_over_3": float(np.mean(np.abs(z) > 3.0)),
                      "max_err_arcsec": float(np.max(np.abs(err)) * 206264.806)}
    # attitude error between the fault and the isolation (degraded: the fault is in the attitude)
    if t_fault is not None and t_iso is not None and run.truth_att:
        win = (t >= t_fault) & (t <= t_iso)
        if win.any():
            q_est = np.array([a[1] for a, s in zip(run.att, win, strict=True) if s])
            err = (Rotation.from_quat(q_est) * _slerp_truth(run.truth_att, t[win]).inv()).as_rotvec()
            out["att_before_isolation_max_arcsec"] = float(np.max(np.abs(err)) * 206264.806)
    # remaining gyros' parameters and φ2 / σ, every param_period after the isolation
    truth_t = np.array([m["t_bus"] for m in run.truth_par]) if run.truth_par else np.zeros(0)
    zmax, zlast = 0.0, None
    n_checks = 0
    for tp, est, sig, excl in run.params:
        if t_iso is not None and tp <= t_iso:
            continue
        if not truth_t.size:
            break
        tr = run.truth_par[int(np.clip(np.searchsorted(truth_t, tp), 0, truth_t.size - 1))]
        zs = []
        for g in PARAM_GROUPS:
            for i, (x, s, xt) in enumerate(zip(est[g], sig[g], tr[g], strict=True)):
                if g != "phi2" and i in excl:
                    continue
                zs.append((x - xt) / s)
        zs = np.asarray(zs)
        zmax = max(zmax, float(np.max(np.abs(zs))))
        zlast = zs
        n_checks += 1
    out["params"] = {"checks": n_checks, "max_abs_z": zmax,
                     "final_max_abs_z": float(np.max(np.abs(zlast))) if zlast is not None else None,
                     "n_states": int(zlast.size) if zlast is not None else 0}
    return out
