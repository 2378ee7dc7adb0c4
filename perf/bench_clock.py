"""Accuracy and speed of the SIRU clock reconstruction against the simulator's truth.

For each SIRU oscillator offset (−100, −30, +30, +100 ppm; sample jitter 1 µs, read jitter 20 µs,
the simulator's defaults) it synthesizes a seeded, network-free archive with a 2**32 counter wrap
and a counter reset, streams its ``/siru`` messages through :class:`radical_rt.clock.siru_clock.SiruClock`
(``reconstruct`` and ``naive``), and compares each released sample's time with
``/truth/siru_time``. Profiles: ``smoke`` (±100 ppm, 300 s, for the test suite), ``quick``
(600 s), ``full`` (3600 s; the table in docs/clock.md).

Command: ``python -m perf.bench_clock [--profile smoke|quick|full] [--out DIR]``. It writes
``DIR/clock_<profile>.json`` and prints a Markdown table:

| column | meaning |
|---|---|
| ppm | SIRU oscillator offset ε (truth) |
| est ppm | the clock's final estimate of ε |
| naive RMS / std / max | error of the bus tag of each sample's first read (`mode="naive"`), ms |
| all RMS / max | reconstructed time error over every sample, µs |
| locked RMS / max | the same over samples released while the clock reported `locked` (before and after their message), µs |
| unlocked RMS | error over the other samples (before the first wrap ~T/√12 = 2.9 ms), µs |
| locked % | share of samples released while locked |
| gain | naive RMS / locked RMS |
| rep, miss | repeated and missing reads counted by the clock = truth (✓) |
| ns/read msg / bulk | clock time per read: 10-read messages as in the archive (Python call
  overhead included) / all reads in one push |

and a second table by regime: the reconstructed-time error before the clock has found the first
sawtooth crossing, between its first two crossings, and from the second on (a crossing is found
once its spate has settled, about 1–2 s after the true wrap; true wrap times listed beside).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from radical_rt.clock.clock_config import ClockConfig
from radical_rt.clock.siru_clock import SiruClock

PROFILES = {"smoke": ((-100.0, 100.0), 300.0), "quick": ((-100.0, -30.0, 30.0, 100.0), 600.0),
            "full": ((-100.0, -30.0, 30.0, 100.0), 3600.0)}
DEFAULT_OUT = Path(__file__).resolve().parent / "results"
T = 0.01


def scenario(eps_ppm: float, duration_s: float) -> dict:
    """Built-in 2006216 with offset ε, the 2**32 wrap at 1/3 and a counter reset at 2/3 of the run."""
    n_wrap = int(duration_s / 3 / T)
    return {"base": "2006216", "name": f"clock-{eps_ppm:+.0f}ppm",
            "siru": {"eps_ppm": eps_ppm, "tt0": 2**32 - 10000 * n_wrap - 1234,
                     "tt_reset_s": [round(2 * duration_s / 3, 3) + 0.0037]}}


def read_archive(path: str | Path) -> dict:
    """The ``/siru`` messages (as column arrays), the truth ``tt``/``t_true`` and truth counts."""
    from radical_rt.io.archive import ArchiveReader

    reader = ArchiveReader(path)
    msgs, tt_true, t_true = [], [], []
    for topic, _t, msg in reader.iter_messages(topics=["/siru", "/truth/siru_time"]):
        if topic == "/siru":
            msgs.append((np.asarray(msg["t_bus"], float), np.asarray(msg["tt"], np.int64),
                         np.asarray(msg["dtheta"], float), np.asarray(msg["status"], np.int64)))
        else:
            tt_true.append(msg["tt"])
            t_true.append(msg["t_true"])
    counts = json.loads(reader.scenario["truth_counts"])
    return {"msgs": msgs, "tt": np.concatenate(tt_true).astype(np.int64),
            "t_true": np.concatenate(t_true), "counts": counts, "meta": dict(reader.scenario)}


def run_clock(msgs, mode: str = "reconstruct") -> dict:
    """Stream the messages through a fresh clock; per released sample: t, tt (−1 if bridged) and
    whether the clock reported `locked` both before and after the message that released it."""
    clock = SiruClock(ClockConfig(mode=mode))
    ts, tts, locked, cross = [], [], [], []
    t0 = time.perf_counter()
    for m in msgs:
        before = clock.locked
        n_before = clock.counters["crossings"]
        b = clock.push(*m)
        ts.append(b.t)
        tts.append(clock.last_tt)
        locked.append(np.full(len(b.t), before and clock.locked))
        cross.append(np.full(len(b.t), n_before))
    b = clock.flush()
    elapsed = time.perf_counter() - t0
    ts.append(b.t)
    tts.append(clock.last_tt)
    locked.append(np.full(len(b.t), False))
    cross.append(np.full(len(b.t), clock.counters["crossings"]))
    return {"t": np.concatenate(ts), "tt": np.concatenate(tts), "locked": np.concatenate(locked),
            "crossings": np.concatenate(cross), "counters": clock.counters,
            "telemetry": clock.telemetry(), "elapsed_s": elapsed}


def match_truth(tt_out: np.ndarray, tt_true: np.ndarray) -> np.ndarray:
    """Index into the truth rows of each released (non-bridged) sample, matching time tags in
    order (tags repeat after a wrap or a reset, order does not); −1 where a tag has no later
    truth row (should not happen)."""
    idx = np.full(tt_out.size, -1, np.int64)
    truth, p, n = tt_true.tolist(), 0, tt_true.size
    for i, q in enumerate(tt_out.tolist()):
        while p < n and truth[p] != q:
            p += 1
        if p == n:
            break
        idx[i] = p
    return idx


def _stats(err: np.ndarray) -> dict:
    if err.size == 0:
        return {"n": 0, "rms_s": None, "max_s": None, "mean_s": None, "std_s": None}
    return {"n": int(err.size), "rms_s": float(np.sqrt(np.mean(err**2))),
            "max_s": float(np.max(np.abs(err))), "mean_s": float(np.mean(err)),
            "std_s": float(np.std(err))}


def wrap_times(err_naive: np.ndarray, t_true: np.ndarray, sep_s: float = 20.0) -> list[float]:
    """True times of the sawtooth wraps: where the naive tag error jumps by more than T/2
    (a jitter spate within ``sep_s`` counts once)."""
    times: list[float] = []
    for t in t_true[1:][np.abs(np.diff(err_naive)) > T / 2]:
        if not times or t - times[-1] > sep_s:
            times.append(float(t))
    return times


def phases(err: np.ndarray, crossings: np.ndarray) -> dict:
    """Error statistics by the crossings the clock had found when it released each sample (the
    count before its message): none yet, one, two or more."""
    return {"before_wrap1": _stats(err[crossings == 0]),
            "wrap1_to_wrap2": _stats(err[crossings == 1]),
            "after_wrap2": _stats(err[crossings >= 2])}


def evaluate(path: str | Path) -> dict:
    """Clock accuracy on one archive: naive and reconstructed errors, counts versus truth."""
    data = read_archive(path)
    out: dict = {"truth_counts": data["counts"]}
    errs = {}
    for mode in ("naive", "reconstruct"):
        r = run_clock(data["msgs"], mode)
        real = r["tt"] >= 0
        idx = match_truth(r["tt"][real], data["tt"])
        if (idx < 0).any():
            raise ValueError(f"{path}: released samples without a truth row")
        err = r["t"][real] - data["t_true"][idx]
        errs[mode] = (err, data["t_true"][idx], r["crossings"][real])
        locked = r["locked"][real]
        n_reads = sum(len(m[0]) for m in data["msgs"])
        out[mode] = {"all": _stats(err), "locked": _stats(err[locked]),
                     "unlocked": _stats(err[~locked]),
                     "locked_fraction": float(np.mean(locked)), "counters": r["counters"],
                     "telemetry": r["telemetry"], "ns_per_read": r["elapsed_s"] / n_reads * 1e9,
                     "bulk_ns_per_read": bulk_ns_per_read(data["msgs"], mode)}
    out["wrap_times_s"] = wrap_times(*errs["naive"][:2])
    out["t_first_s"] = float(data["t_true"][0])
    out["reconstruct"]["phases"] = phases(errs["reconstruct"][0], errs["reconstruct"][2])
    return out


def bulk_ns_per_read(msgs, mode: str = "reconstruct") -> float:
    """Clock time per read when all reads come in one push (the batch engine's best case)."""
    cols = [np.concatenate([m[i] for m in msgs]) for i in range(4)]
    clock = SiruClock(ClockConfig(mode=mode))
    t0 = time.perf_counter()
    clock.push(*cols)
    clock.flush()
    return (time.perf_counter() - t0) / len(cols[0]) * 1e9


def run(profile: str = "quick", out_dir: str | Path | None = None) -> dict:
    """Run one profile (see the module docstring); writes ``clock_<profile>.json`` to out_dir."""
    if profile not in PROFILES:
        raise ValueError(f"unknown profile {profile!r}; use one of {', '.join(PROFILES)}")
    from replayer.synth import synthesize

    offsets, duration = PROFILES[profile]
    rows = []
    SiruClock().push([0.0], [0], np.zeros((1, 4)), [0])  # compile (or load) outside the timing
    with tempfile.TemporaryDirectory() as tmp:
        for eps in offsets:
            path = Path(tmp) / f"clock_{eps:+.0f}.mcap"
            synthesize(scenario(eps, duration), path, seed=1, duration=duration)
            row = evaluate(path)
            row["eps_ppm"] = eps
            rows.append(row)
    report = {"schema": "radical.bench.clock/1", "profile": profile, "duration_s": duration,
              "seed": 1, "rows": rows, "python": platform.python_version(),
              "machine": platform.machine()}
    out = Path(out_dir) if out_dir is not None else DEFAULT_OUT
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"clock_{profile}.json"
    path.write_text(json.dumps(report, indent=1))
    report["json_path"] = str(path)
    return report


def markdown(report: dict) -> str:
    """The Markdown table of the module docstring."""
    lines = ["| ppm | est ppm | naive RMS / std / max (ms) | all RMS / max (µs) | "
             "locked RMS / max (µs) | unlocked RMS (µs) | locked % | gain | rep (truth) | "
             "miss (truth) | ns/read msg / bulk |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in report["rows"]:
        nv, rc, tc = r["naive"]["all"], r["reconstruct"], r["truth_counts"]
        c, lk = rc["counters"], rc["locked"]
        ok_r = "✓" if c["repeated"] == tc["n_repeated"] else "✗"
        ok_m = "✓" if c["missing"] == tc["n_missing"] else "✗"
        gain = nv["rms_s"] / lk["rms_s"] if lk["n"] else float("nan")
        lk_txt = f"{lk['rms_s'] * 1e6:.2f} / {lk['max_s'] * 1e6:.1f}" if lk["n"] else "–"
        ul = rc["unlocked"]
        ul_txt = f"{ul['rms_s'] * 1e6:.0f}" if ul["n"] else "–"
        lines.append(
            f"| {r['eps_ppm']:+.0f} | {rc['telemetry']['freq_offset_ppm']:+.3f} | "
            f"{nv['rms_s'] * 1e3:.2f} / {nv['std_s'] * 1e3:.2f} / {nv['max_s'] * 1e3:.2f} | "
            f"{rc['all']['rms_s'] * 1e6:.0f} / {rc['all']['max_s'] * 1e6:.0f} | {lk_txt} | "
            f"{ul_txt} | {100 * rc['locked_fraction']:.0f} | {gain:.0f}× | "
            f"{c['repeated']} ({tc['n_repeated']}) {ok_r} | {c['missing']} ({tc['n_missing']}) "
            f"{ok_m} | {rc['ns_per_read']:.0f} / {rc['bulk_ns_per_read']:.0f} |")
    lines += ["", "| ppm | first wraps (s) | before wrap 1: RMS / max (µs) | "
              "wrap 1 → 2: RMS / max (µs) | after wrap 2: RMS / max (µs) |", "|---|---|---|---|---|"]
    for r in report["rows"]:
        ph = r["reconstruct"]["phases"]
        t0 = r["t_first_s"]
        cells = [f"{ph[k]['rms_s'] * 1e6:.0f} / {ph[k]['max_s'] * 1e6:.0f}" if ph[k]["n"] else "–"
                 for k in ("before_wrap1", "wrap1_to_wrap2")]
        a = ph["after_wrap2"]
        cells.append(f"{a['rms_s'] * 1e6:.2f} / {a['max_s'] * 1e6:.0f}" if a["n"] else "–")
        w = ", ".join(f"{x - t0:.0f}" for x in r["wrap_times_s"][:2])
        lines.append(f"| {r['eps_ppm']:+.0f} | {w} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m perf.bench_clock",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--profile", choices=sorted(PROFILES), default="full")
    ap.add_argument("--out", default=str(DEFAULT_OUT), help="output directory for the JSON")
    args = ap.parse_args(argv)
    report = run(args.profile, args.out)
    print(markdown(report))
    print(f"\nwrote {report['json_path']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
