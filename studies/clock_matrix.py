"""Clock robustness matrix (issue 17): the SIRU clock and everything downstream on telemetry
with tick tags, read offsets, heavy read jitter, late reads, ε of either sign, counter wraps and
resets, and data gaps.

    python -m studies.clock_matrix [--quick] [--only NAME[,NAME]] [--out DIR] [--jobs N] [--keep]

For each case of :mod:`studies.clock_matrix_cases` (26 seeded 1-hour cases; ``--quick``: 4 cases
of 300–600 s) it synthesizes the archive (``radical synth``'s API, built-in 2006216 as the base),
runs ``radical process`` on it in-process (``radical_rt.apps.batch.process``) and streams the
archive's ``/siru`` messages through a fresh :class:`radical_rt.clock.siru_clock.SiruClock`. Measured (see
:mod:`studies.clock_matrix_metrics`):

| column | meaning | aim (PASS) |
|---|---|---|
| lock s | time to lock: from the run start (and after each injected reset / gap end) to the first message from which the clock stays `locked` to the next such event or the end | every segment ≤ min(2·T/\\|ε\\|, 300 s); a segment shorter than that must be locked at its end, if at all |
| 2nd wrap | the true time of the second sawtooth wrap (first jump of the naive tag error), the earliest a lock is possible from tags (docs/clock.md, "Locking") | lock ≤ 2nd wrap + max(10 s, 30 σ_jitter/\\|ε\\|) (the spate, heavy tails included, must settle) |
| Δf ppm | clock frequency estimate − ε at the end (truth `siru.eps_ppm`) | ≤ 0.1 ppm and locked |
| RMS µs | reconstructed sample times − `/truth/siru_time`, samples released while locked, constant offset removed | ≤ jit + 20 µs |
| jit µs | the jitter's own contribution: RMS of the true times about their best line | — |
| off µs | the removed constant offset (≈ the read offset in tick mode) | — |
| rep, miss | summary `siru_repeated`, `siru_missing` (and `siru_samples`) − the simulator's truth | exact |
| anom s | seconds of CLOCK_ANOMALY outside 1 s before / 10 s after an injected reset or gap (total in brackets) | 0 |
| alarm s | seconds of PARITY_ALARM + GYRO_x_FAILED (all cases are fault-free) | 0 |
| lat z | (latency estimate − truth)/σ; truth = `trackers.latency_s` − mean read lead (`siru_timing.latency_truth_s`): the constant read offset goes into the latency | \\|z\\| ≤ 3 |
| max z | worst \\|error\\|/σ of the 23 parameters against the last `/truth/params` | 23/23 ≤ 3 |
| conv | summary `converged` at the end | true |
| run s | wall time of `process` | — |

Writes ``DIR/clock_matrix[_quick].json`` (every measurement, SI and display units) and
``DIR/clock_matrix[_quick].md`` (the table for docs/clock.md). Archives go to ``DIR/cases/`` and
are deleted after a case unless ``--keep``. Exit status 0 whatever the aims say.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import platform
import sys
import time
from pathlib import Path

from tqdm import tqdm

from studies import clock_matrix_metrics as M
from studies.clock_matrix_cases import CASES, QUICK, Case, by_name, scenario

AIMS = ("lock", "lock_wrap2", "freq", "timeline", "counts", "anomaly", "alarms", "latency", "params",
        "converged")
#: the aims that apply to the short runs of --quick (tests/studies/test_clock_matrix.py)
QUICK_AIMS = ("lock", "lock_wrap2", "freq", "timeline", "counts", "anomaly", "alarms")
FREQ_AIM_PPM, TIMELINE_AIM_US, Z_AIM = 0.1, 20.0, 3.0
ALARM_FLAGS = ("PARITY_ALARM", "GYRO_A_FAILED", "GYRO_B_FAILED", "GYRO_C_FAILED", "GYRO_D_FAILED")


def run_case(case: Case, workdir: str | Path, keep: bool = False) -> dict:
    """Synthesize, process and measure one case; returns its row (see the module docstring)."""
    from radical_rt.apps.batch import process
    from replayer.synth import synthesize

    work = Path(workdir)
    work.mkdir(parents=True, exist_ok=True)
    src, out, summ = (work / f"{case.name}{s}" for s in (".mcap", "_out.mcap", "_summary.json"))
    t0 = time.perf_counter()
    synthesize(scenario(case), src)
    t_synth = time.perf_counter() - t0
    t0 = time.perf_counter()
    summary = process([str(src)], str(out), str(summ))
    t_proc = time.perf_counter() - t0
    data = M.read_input(src)
    run = M.clock_run(data["msgs"])
    t_end = case.duration_s
    segs = M.lock_times(run["t_msg"], run["locked_msg"], 0.0, t_end, case.events_s)
    t_lock = segs[0]["delay_s"]
    tl = M.timeline(run, data["tt"], data["t_true"])
    freq = M.freq_after_lock(run, case.eps_ppm, t_lock)
    tim = data["timing"]
    t0_run = float(scenario(case).get("t_start_s", 0.0))
    wraps = [w - t0_run for w in M.true_wraps(data["t_true"], tim["read_lead_mean_s"],
                                              tim["bus_period_s"], t0_run, case.sawtooth_s / 2)]
    secs, rises, spans = M.flag_seconds(out, max(t_end, float(summary["t_end"])))
    events = [(r, r) for r in case.resets_s] + list(case.gaps)
    truth_c, c = data["counts"], summary["counters"]
    lat = summary["latency_st"]
    lat_truth = data["timing"]["latency_truth_s"]
    row = {
        "case": case.to_dict(), "sawtooth_s": case.sawtooth_s, "lock_limit_s": case.lock_limit_s,
        "lock_segments": segs, "t_lock_s": t_lock, **freq, **tl,
        "wraps_s": wraps, "wrap2_s": wraps[1] if len(wraps) > 1 else None,
        "counts": {"siru_samples": [c["siru_samples"], truth_c["n_distinct"]],
                   "siru_repeated": [c["siru_repeated"], truth_c["n_repeated"]],
                   "siru_missing": [c["siru_missing"], truth_c["n_missing"]]},
        "clock_counters": run["counters"], "clock_telemetry": run["telemetry"],
        "flag_seconds": {k: v for k, v in secs.items() if v > 0},
        "flag_rises": {k: v for k, v in rises.items() if v > 0},
        "anomaly_s": secs["CLOCK_ANOMALY"], "anomaly_unexpected_s": M.unexpected_anomaly_s(
            spans, events),
        "alarm_s": sum(secs[k] for k in ALARM_FLAGS), "alarm_rises": sum(rises[k] for k in ALARM_FLAGS),
        "latency": {**lat, "truth_s": lat_truth,
                    "z": (lat["estimate_s"] - lat_truth) / lat["sigma_s"] if lat["sigma_s"] > 0
                    else None},
        "params": M.param_z(summary, src), "converged": bool(summary["converged"]),
        "mode": summary["mode"], "timing_truth": data["timing"], "synth_s": t_synth,
        "process_s": t_proc,
    }
    row["aims"] = aims(row, case)
    if not keep:
        for p in (src, out, summ):
            p.unlink(missing_ok=True)
    return row


def aims(row: dict, case: Case) -> dict[str, bool]:
    """PASS (True) / FAIL (False) per aim of issue 17 (see the module docstring)."""
    lim = case.lock_limit_s
    lock_ok = all(s["delay_s"] is not None and s["delay_s"] <= lim
                  for s in row["lock_segments"] if s["length_s"] > lim or s["delay_s"] is not None)
    lock_ok = lock_ok and row["t_lock_s"] is not None
    locked_end = bool(row["clock_telemetry"]["locked"])
    rms, jit = row["locked_rms_us"], row["jitter_us"]
    z = row["latency"]["z"]
    p = row["params"]
    w2 = row.get("wrap2_s")
    settle = max(10.0, 30.0 * case.jitter_s / abs(case.eps_ppm * 1e-6))
    return {
        "lock": lock_ok,
        "lock_wrap2": (w2 is None or row["t_lock_s"] is not None and row["t_lock_s"] <= w2 + settle),
        "freq": locked_end and abs(row["freq_err_ppm"]) <= FREQ_AIM_PPM,
        "timeline": rms is not None and rms <= jit + TIMELINE_AIM_US,
        "counts": all(a == b for a, b in row["counts"].values()),
        "anomaly": row["anomaly_unexpected_s"] == 0.0,
        "alarms": row["alarm_s"] == 0.0 and row["alarm_rises"] == 0,
        "latency": z is not None and abs(z) <= Z_AIM,
        "params": p["max_abs_z"] is not None and p["n_within_3sigma"] == p["n_params"],
        "converged": row["converged"],
    }


def _worker(args: tuple[str, str, bool]) -> dict:
    name, workdir, keep = args
    case = by_name(name)
    try:
        return run_case(case, workdir, keep)
    except Exception as exc:  # a crash is a result of the matrix, not the end of it
        return {"case": case.to_dict(), "error": f"{type(exc).__name__}: {exc}",
                "aims": dict.fromkeys(AIMS, False)}


def run(cases: list[Case], out_dir: str | Path, jobs: int = 1, keep: bool = False,
        progress: bool = True, tag: str = "") -> dict:
    """Run the cases (``jobs`` worker processes); write and return the report."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    work = str(out / "cases")
    tasks = [(c.name, work, keep) for c in cases]
    t0 = time.perf_counter()
    with tqdm(total=len(tasks), unit="case", desc="clock matrix", disable=not progress,
              file=sys.stderr) as bar:
        if jobs <= 1:
            rows = []
            for t in tasks:
                rows.append(_worker(t))
                bar.update(1)
        else:
            with mp.get_context("spawn").Pool(jobs) as pool:
                rows = []
                for r in pool.imap_unordered(_worker, tasks):
                    rows.append(r)
                    bar.update(1)
    order = {c.name: i for i, c in enumerate(cases)}
    rows.sort(key=lambda r: order[r["case"]["name"]])
    report = {"schema": "radical.study.clock_matrix/1", "rows": rows, "jobs": jobs,
              "elapsed_s": time.perf_counter() - t0, "python": platform.python_version(),
              "machine": platform.machine(),
              "aims": {"freq_ppm": FREQ_AIM_PPM, "timeline_us": TIMELINE_AIM_US, "z": Z_AIM},
              "passed": {a: sum(bool(r["aims"][a]) for r in rows) for a in AIMS}}
    stem = f"clock_matrix{tag}"
    (out / f"{stem}.json").write_text(json.dumps(report, indent=1, default=str) + "\n")
    (out / f"{stem}.md").write_text(markdown(report) + "\n")
    report["paths"] = [str(out / f"{stem}.json"), str(out / f"{stem}.md")]
    return report


def _f(v, fmt: str, none: str = "—") -> str:
    return none if v is None else format(v, fmt)


def _lock_cell(r: dict) -> str:
    """First lock time, then the re-lock delays after each injected reset / gap end (s)."""
    cell = _f(r["t_lock_s"], ".0f", "never")
    rel = [_f(s["delay_s"], ".0f", "never") for s in r["lock_segments"][1:]]
    return cell + (f"; relock {', '.join(rel)}" if rel else "")


def _mark(ok: bool) -> str:
    return "✓" if ok else "✗"


def markdown(report: dict) -> str:
    """The Markdown table of the module docstring (✓/✗ = the aim's PASS/FAIL)."""
    head = ("| case | tags | offset ms | read jitter | ε ppm | discontinuities | "
            "lock s (aim) [true 2nd wrap] | "
            "Δf ppm | RMS / jit / off µs | rep, miss (truth) | anom s | alarm s | lat z | "
            "max z | conv | run s | pass |")
    lines = [head, "|" + "---|" * 17]
    for r in report["rows"]:
        c = Case.from_dict(r["case"])
        if "error" in r:
            lines.append(f"| {c.name} | {c.tag_mode} | | | | | error: {r['error']} |" + " |" * 10)
            continue
        a = r["aims"]
        rep, miss = r["counts"]["siru_repeated"], r["counts"]["siru_missing"]
        lines.append(
            f"| {c.name} | {c.tag_mode} | {c.offset_s * 1e3:g} | {c.jitter_label()} | "
            f"{c.eps_ppm:+g} | {c.disc_label()} | "
            f"{_lock_cell(r)} ({c.lock_limit_s:.0f}) {_mark(a['lock'])} "
            f"[2nd wrap {_f(r.get('wrap2_s'), '.0f', '–')}] {_mark(a['lock_wrap2'])} | "
            f"{r['freq_err_ppm']:+.3f} {_mark(a['freq'])} | "
            f"{_f(r['locked_rms_us'], '.1f')} / {_f(r['jitter_us'], '.1f')} / "
            f"{_f(r['offset_us'], '.0f')} {_mark(a['timeline'])} | "
            f"{rep[0]}, {miss[0]} ({rep[1]}, {miss[1]}) {_mark(a['counts'])} | "
            f"{r['anomaly_unexpected_s']:.0f} ({r['anomaly_s']:.0f}) {_mark(a['anomaly'])} | "
            f"{r['alarm_s']:.0f} {_mark(a['alarms'])} | "
            f"{_f(r['latency']['z'], '+.1f')} {_mark(a['latency'])} | "
            f"{_f(r['params']['max_abs_z'], '.2f')} {_mark(a['params'])} | "
            f"{_mark(a['converged'])} | {r['process_s']:.1f} | "
            f"{sum(map(bool, a.values()))}/{len(a)} |")
    n = len(report["rows"])
    lines.append("")
    lines.append("Cases passing each aim: " + ", ".join(
        f"{k} {v}/{n}" for k, v in report["passed"].items()) + ".")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="the shortened subset (4 cases, 300–600 s)")
    ap.add_argument("--only", help="comma-separated case names (of the full or quick table)")
    ap.add_argument("--out", default="out/clock_matrix", help="result and working directory")
    ap.add_argument("--jobs", type=int, default=1, help="worker processes (default 1)")
    ap.add_argument("--keep", action="store_true", help="keep the archives in OUT/cases")
    a = ap.parse_args(argv)
    try:
        cases = [by_name(n) for n in a.only.split(",")] if a.only else list(QUICK if a.quick else CASES)
    except KeyError as exc:
        print(f"clock_matrix: {exc.args[0]}", file=sys.stderr)
        return 2
    tag = "_quick" if a.quick else ("_only" if a.only else "")
    report = run(cases, a.out, jobs=max(1, a.jobs), keep=a.keep, tag=tag)
    print(markdown(report))
    print("\n".join(report["paths"]), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
