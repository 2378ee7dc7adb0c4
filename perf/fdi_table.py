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

The cases and their evaluation (:func:`~perf.fdi_cases.fault_toml`, :class:`~perf.fdi_cases.Run`,
:func:`~perf.fdi_cases.evaluate`) are in :mod:`perf.fdi_cases`, also used by the FDI tests.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from perf.fdi_cases import DURATION, FAULT_T, KINDS, SEED, SPLIT_T, Run, evaluate, fault_toml, synth

GYRO_NAMES = "ABCD"
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
MESSENGER_MOVES = [("x", 10.0, 240.0), ("x", -20.0, 240.0), ("x", 10.0, 240.0), ("z", 10.0, 240.0),
                   ("z", -20.0, 240.0), ("z", 10.0, 240.0), ("y", 360.0, 60.0), ("y", -360.0, 600.0)]


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
