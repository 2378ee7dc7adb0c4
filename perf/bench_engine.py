"""Engine throughput: seconds of telemetry processed per wall second (batch shell, one core).

Command::

    python -m perf.bench_engine [--profile smoke|quick|full] [--out DIR]

The scenario (2006216, seeded, bus time starting at 1000 s) is synthesized outside the timed region.
A first, untimed pass over a short prefix compiles/loads the Numba kernels (its time is reported
as ``warmup_s``); the timed pass runs ``radical process`` (no output archive) over the whole
archive. ``x_realtime`` = telemetry seconds / wall seconds; ``us_per_gyro_sample`` = wall time per
distinct SIRU sample (everything included: MCAP reading, decoding, clock, engine, packets).
The process is pinned to one CPU when the platform allows it.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
from pathlib import Path
from typing import Any

PROFILES = {"smoke": 30.0, "quick": 600.0, "full": 7200.0}
SCENARIO_TOML = 'base = "2006216"\nt_start_s = 1000.0\n'
DEFAULT_OUT = Path(__file__).resolve().parent / "results"


def run(profile: str = "quick", out_dir: str | Path | None = None) -> dict[str, Any]:
    """Synthesize, warm up, then time the batch engine; returns (and writes) the result dict."""
    from radical_rt.batch import process
    from replayer.synth.api import synthesize

    if profile not in PROFILES:
        raise ValueError(f"unknown profile {profile!r}; use one of {', '.join(PROFILES)}")
    try:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
        pinned = True
    except (AttributeError, OSError):
        pinned = False
    with tempfile.TemporaryDirectory() as tmp:
        toml = Path(tmp) / "s.toml"
        toml.write_text(SCENARIO_TOML)
        sim = Path(tmp) / "sim.mcap"
        warm = Path(tmp) / "warm.mcap"
        synthesize(str(toml), sim, seed=1, duration=PROFILES[profile])
        synthesize(str(toml), warm, seed=2, duration=5.0)
        t0 = time.perf_counter()
        process([str(warm)], None, None)
        t1 = time.perf_counter()
        summary = process([str(sim)], None, None)
        t2 = time.perf_counter()
    wall = t2 - t1
    n = summary["counters"]["siru_samples"]
    res = {"bench": "engine", "profile": profile, "telemetry_s": PROFILES[profile],
           "wall_s": wall, "x_realtime": PROFILES[profile] / wall,
           "us_per_gyro_sample": 1e6 * wall / max(n, 1), "siru_samples": n,
           "warmup_s": t1 - t0, "pinned_one_cpu": pinned}
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        (Path(out_dir) / f"engine_{profile}.json").write_text(json.dumps(res, indent=1))
    return res


def markdown(res: dict[str, Any]) -> str:
    return ("| telemetry s | wall s | × real time | µs / gyro sample | warm-up s |\n|---|---|---|---|---|\n"
            f"| {res['telemetry_s']:.0f} | {res['wall_s']:.2f} | {res['x_realtime']:.0f} | "
            f"{res['us_per_gyro_sample']:.2f} | {res['warmup_s']:.2f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--profile", default="quick", choices=list(PROFILES))
    ap.add_argument("--out", default=str(DEFAULT_OUT))
    a = ap.parse_args()
    print(markdown(run(a.profile, a.out)))


if __name__ == "__main__":
    main()
