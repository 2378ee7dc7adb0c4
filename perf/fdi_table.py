"""Regenerate the FDI figures of docs/fdi.md: detection and isolation per gyro and fault type, and the
false alarms over a long nominal run.

Command::

    python -m perf.fdi_table [--out DIR] [--nominal-hours 10] [--gyros 0 1 2 3] [--kinds ...]

What it does (progress on stderr, results in DIR/fdi_table.json and DIR/fdi_table.md):

1. Synthesizes the 2006216 scenario (seed 1, 3600 s; cold start, x/z slews, then the +360° y
   slew) and, for every gyro and fault kind, the same scenario with one fault starting at
   ``FAULT_T`` = 2400 s (mid y slew, 0.3 deg/s). The fault archives are identical to the nominal
   one before the fault (checked message by message), so the engine runs the common prefix once
   and each fault case continues from a deep copy of the processor at ``SPLIT_T``.
2. For each case: detection delay (PARITY_ALARM) and isolation (which gyro, delay) from the
   FaultMonitor records, and after the isolation the attitude error against ``/truth/attitude``
   (1 Hz, per body axis, in units of the engine's σ) and the remaining gyros' parameters and φ2
   against ``/truth/params`` every 60 s (CONTRACT parameters, in units of the engine's σ).
3. Further cases (``EXTRAS``): smaller steps and a ramp (CUSUM), a scale jump during a hold, and
   faults during a cold start (full runs of ``COLD_DURATION`` s); ``--no-extras`` skips them.
4. A long nominal run (``--nominal-hours``, default 10 h: the 2006216 maneuver repeated, cold start)
   for the false-alarm figure.

The helpers (:func:`fault_toml`, :class:`Run`, :func:`evaluate`) are also used by tests/test_fdi.py.
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import json
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

FAULT_T = 2400.0  # fault onset, s from the run start (mid +360° y slew)
SPLIT_T = 2390.0  # the fault cases continue from a copy of the nominal processor at this time
DURATION = 3600.0
SEED = 1
GYRO_NAMES = "ABCD"
KINDS = {  # label → [[faults]] entries besides kind/gyro/start_s
    "bias 0.5 deg/hr": {"kind": "bias_step", "bias_deg_hr": 0.5},
    "bias 5 deg/hr": {"kind": "bias_step", "bias_deg_hr": 5.0},
    "scale +1000 ppm": {"kind": "scale_jump", "lam_ppm": 1000.0},
    "zero output": {"kind": "zero"},
    "noise 0.1\"/sample": {"kind": "noise_burst", "sigma_arcsec": 0.1},
}
#: Further cases (label, gyro, fault with its start_s, how): "fork" continues the nominal run from
#: SPLIT_T like the table; "cold" is a full cold-start run of COLD_DURATION s.
EXTRAS = [
    ("bias 0.05 deg/hr", 1, {"kind": "bias_step", "bias_deg_hr": 0.05, "start_s": FAULT_T}, "fork"),
    ("bias 0.02 deg/hr", 2, {"kind": "bias_step", "bias_deg_hr": 0.02, "start_s": FAULT_T}, "fork"),
    ("bias ramp 2 deg/hr/hr", 0, {"kind": "bias_ramp", "rate_deg_hr_per_hr": 2.0,
                                  "start_s": FAULT_T}, "fork"),
    ("scale +1000 ppm in the hold at 3370 s", 3, {"kind": "scale_jump", "lam_ppm": 1000.0,
                                                   "start_s": 3370.0}, "fork"),
    ("cold start: bias 5 deg/hr at 150 s", 0, {"kind": "bias_step", "bias_deg_hr": 5.0,
                                               "start_s": 150.0}, "cold"),
    ("cold start: zero output at 40 s", 3, {"kind": "zero", "start_s": 40.0}, "cold"),
    ("cold start: scale +1000 ppm at 320 s", 2, {"kind": "scale_jump", "lam_ppm": 1000.0,
                                                 "start_s": 320.0}, "cold"),
]
COLD_DURATION = 1500.0
INPUTS = ("/siru", "/st1", "/st2", "/temp")
TRUTH = ("/truth/attitude", "/truth/params")
MESSENGER_MOVES = [("x", 10.0, 240.0), ("x", -20.0, 240.0), ("x", 10.0, 240.0), ("z", 10.0, 240.0),
                   ("z", -20.0, 240.0), ("z", 10.0, 240.0), ("y", 360.0, 60.0), ("y", -360.0, 600.0)]


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
        """An exact copy to continue with other data (the engine's clock source is re-bound)."""
        other = copy.deepcopy(self)
        other.sp.engine.timing_sigma_source = lambda: other.sp.clock.tag_error_sigma_s
        return other

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


# ----------------------------------------------------------------------------- the table
def _progress(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def fault_cases(gyros, kinds) -> list[tuple[int, str, dict]]:
    return [(g, k, {**KINDS[k], "gyro": g, "start_s": FAULT_T}) for k in kinds for g in gyros]


def run_fault_table(work: Path, gyros, kinds, with_extras: bool = True) -> dict[str, Any]:
    _progress(f"[fdi_table] synthesizing the nominal {DURATION:.0f} s scenario (seed {SEED})")
    nominal = synth(fault_toml(None), work / "nominal.mcap")
    base = Run()
    _progress(f"[fdi_table] nominal run to the split at {SPLIT_T:.0f} s (cold start, x/z slews)")
    h_nom = hashlib.sha256()
    base.feed_archive(nominal, t_to=SPLIT_T)
    fork = base.fork()
    fork.feed_archive(nominal, t_from=SPLIT_T, prefix_hash=h_nom)
    fork.finish()
    rows = [{"gyro": None, "kind": "none", **evaluate(fork, None)}]
    _progress(f"[fdi_table] nominal: alarms {len(fork.sp.engine.fdi.alarms)}, "
              f"wall {base.wall + fork.wall:.0f} s")
    cases = fault_cases(gyros, kinds)
    for n, (g, kind, fault) in enumerate(cases, 1):
        t0 = time.perf_counter()
        path = synth(fault_toml(fault), work / f"fault_{g}_{n}.mcap")
        run = base.fork()
        h = hashlib.sha256()
        run.feed_archive(path, t_from=SPLIT_T, prefix_hash=h)
        if h.digest() != h_nom.digest():
            raise RuntimeError(f"{path}: the archive differs from the nominal one before the split")
        run.finish()
        row = {"gyro": g, "kind": kind, **evaluate(run, FAULT_T)}
        rows.append(row)
        path.unlink()
        _report(f"{n}/{len(cases)}", row, t0)
    extras = []
    for n, (label, g, fault, how) in enumerate(EXTRAS if with_extras else [], 1):
        t0 = time.perf_counter()
        if how == "fork":
            path = synth(fault_toml({**fault, "gyro": g}), work / f"extra_{n}.mcap")
            run = base.fork()
            run.feed_archive(path, t_from=SPLIT_T)
        else:
            path = synth(fault_toml({**fault, "gyro": g}, duration=COLD_DURATION),
                         work / f"extra_{n}.mcap")
            run = Run()
            run.feed_archive(path)
        run.finish()
        row = {"gyro": g, "kind": label, "t_fault": fault["start_s"],
               **evaluate(run, fault["start_s"])}
        extras.append(row)
        path.unlink()
        _report(f"extra {n}/{len(EXTRAS)}", row, t0)
    return {"rows": rows, "extras": extras}


def _report(tag: str, row: dict[str, Any], t0: float) -> None:
    _progress(f"[fdi_table] {tag} gyro {GYRO_NAMES[row['gyro']]} {row['kind']}: "
              f"alarm +{_s(row['detect_delay_s'])} s, isolated "
              f"{_g(row['isolated_gyro'])} +{_s(row['isolate_delay_s'])} s, att max|z| "
              f"{row.get('att', {}).get('max_abs_z', float('nan')):.2f}, params max|z| "
              f"{row['params']['max_abs_z']:.2f} ({time.perf_counter() - t0:.0f} s)")


def run_nominal_long(work: Path, hours: float) -> dict[str, Any]:
    """A long cold-start nominal run: the 2006216 maneuver repeated over ``hours``."""
    moves, t = [], 300.0
    per = sum(abs(a) / 0.3 + 20.0 + h for _, a, h in MESSENGER_MOVES)
    while t < hours * 3600.0 - per:
        moves += MESSENGER_MOVES
        t += per
    _progress(f"[fdi_table] synthesizing the {hours:g} h nominal run ({len(moves)} moves)")
    path = synth(fault_toml(None, duration=hours * 3600.0, name="fdi-long", moves=moves),
                 work / "long.mcap")
    run = Run(param_period=600.0)
    from radical_rt.io.archive import ArchiveReader
    with ArchiveReader(str(path)) as reader:
        total = reader.message_counts.get("/siru", 0)
    _progress(f"[fdi_table] long nominal run: {total} SIRU messages")
    t0 = time.perf_counter()

    def report(t: float) -> None:
        _progress(f"[fdi_table]   {t / 3600.0:.0f} of {hours:g} h ({time.perf_counter() - t0:.0f} s), "
                  f"alarms so far {len(run.sp.engine.fdi.alarms)}")

    run.feed_archive(path, progress=report)
    run.finish()
    res = evaluate(run, None)
    res["hours"] = hours
    res["sums"] = run.sp.engine.fdi.counts["sums"]
    path.unlink()
    return res


def _s(x) -> str:
    return "–" if x is None else f"{x:.1f}"


def _g(x) -> str:
    return "none" if x is None else GYRO_NAMES[x]


def _md_rows(rows: list[dict[str, Any]]) -> list[str]:
    lines = ["| fault | gyro | detection delay [s] (test) | isolated | isolation delay [s] | "
             "attitude max \\|err\\| before isolation [″] | "
             "attitude max \\|err\\|/σ after | params max \\|err\\|/σ after |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        test = r["alarms"][0]["test"] if r["alarms"] else "–"
        att = r.get("att", {})
        lines.append(f"| {r['kind']} | {GYRO_NAMES[r['gyro']]} | {_s(r['detect_delay_s'])} ({test}) "
                     f"| {_g(r['isolated_gyro'])} | {_s(r['isolate_delay_s'])} | "
                     f"{_s(r.get('att_before_isolation_max_arcsec'))} | "
                     f"{att.get('max_abs_z', float('nan')):.2f} | "
                     f"{r['params']['max_abs_z']:.2f} |")
    return lines


def markdown(res: dict[str, Any]) -> str:
    lines = _md_rows([r for r in res["fault"]["rows"] if r["gyro"] is not None])
    nom = res["fault"]["rows"][0]
    lines.append("")
    lines.append(f"Nominal {DURATION:.0f} s run (cold start): {len(nom['alarms'])} alarms, "
                 f"{nom['counts']['sums']} parity sums tested.")
    if res["fault"].get("extras"):
        lines += ["", "Further cases:", ""] + _md_rows(res["fault"]["extras"])
    if "long" in res:
        lo = res["long"]
        lines.append("")
        lines.append(f"Long nominal run: {lo['hours']:g} h, {lo['sums']} parity sums, "
                     f"{len(lo['alarms'])} alarms, {len(lo['isolations'])} isolations; "
                     f"attitude max |err|/σ {lo.get('att', {}).get('max_abs_z', float('nan')):.2f} "
                     f"(beyond 3σ: {100 * lo.get('att', {}).get('frac_over_3', float('nan')):.3f} % "
                     f"of the 1-Hz samples), parameters max |err|/σ {lo['params']['max_abs_z']:.2f}.")
    lines.append("")
    lines.append(f"Wall time {res['wall_s']:.0f} s.")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m perf.fdi_table", description=__doc__.split("\n")[0])
    p.add_argument("--out", default=str(Path(__file__).resolve().parent / "results"))
    p.add_argument("--nominal-hours", type=float, default=10.0, help="0 skips the long run")
    p.add_argument("--gyros", type=int, nargs="*", default=[0, 1, 2, 3])
    p.add_argument("--kinds", nargs="*", default=list(KINDS), choices=list(KINDS))
    p.add_argument("--no-extras", action="store_true", help="skip the further cases")
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="fdi_table_") as tmp:
        res: dict[str, Any] = {"fault_t": FAULT_T, "duration": DURATION, "seed": SEED,
                               "fault": run_fault_table(Path(tmp), args.gyros, args.kinds,
                                                         not args.no_extras)}
        if args.nominal_hours > 0:
            res["long"] = run_nominal_long(Path(tmp), args.nominal_hours)
    res["wall_s"] = time.perf_counter() - t0
    (out / "fdi_table.json").write_text(json.dumps(res, indent=1, default=float) + "\n")
    md = markdown(res)
    (out / "fdi_table.md").write_text(md)
    print(md)
    _progress(f"[fdi_table] done in {res['wall_s']:.0f} s; {out / 'fdi_table.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
