"""Benchmark of the telemetry simulator (`radical synth`).

Synthesizes the built-in 2006216 scenario (seeded, network-free) and reports wall time, speed
(simulated seconds per wall second) and archive size. Profiles: ``smoke`` (60 s of simulated
time, for the test suite), ``quick`` (600 s), ``full`` (the whole 7200 s run).

Command: ``python -m perf.bench_synth [--profile quick|full|smoke] [--out DIR]``. It prints one
JSON object and one Markdown table row:

| column | meaning |
|---|---|
| profile | workload name |
| sim_s | simulated seconds |
| wall_s | wall time of ``synthesize`` (s, both passes, archive writing included) |
| speed_x | sim_s / wall_s (times faster than real time) |
| size_MB | archive size (10^6 bytes) |
| messages | messages written, all topics |
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
from pathlib import Path

from replayer.synth import synthesize

PROFILES = {"smoke": 60.0, "quick": 600.0, "full": 7200.0}
SCENARIO = "2006216"


def run(profile: str = "quick", out_dir: str | Path | None = None) -> dict:
    """Run one profile; returns the result dict (see the module docstring for the columns).

    With ``out_dir`` the archive is kept there, else it is written to a temporary directory.
    """
    if profile not in PROFILES:
        raise ValueError(f"unknown profile {profile!r}; use one of {', '.join(PROFILES)}")
    with tempfile.TemporaryDirectory() as tmp:
        where = Path(out_dir) if out_dir is not None else Path(tmp)
        res = synthesize(SCENARIO, where / f"synth_{SCENARIO}_{profile}.mcap",
                         duration=PROFILES[profile])
    sim_s = PROFILES[profile]
    return {"bench": "synth", "profile": profile, "scenario": SCENARIO, "sim_s": sim_s,
            "wall_s": round(res.elapsed_s, 3), "speed_x": round(sim_s / res.elapsed_s, 1),
            "size_bytes": res.file_size, "size_MB": round(res.file_size / 1e6, 2),
            "messages": sum(res.message_counts.values()),
            "python": platform.python_version(), "machine": platform.machine()}


def markdown_row(r: dict) -> str:
    """One Markdown table row: profile | sim_s | wall_s | speed_x | size_MB | messages."""
    return (f"| {r['profile']} | {r['sim_s']:.0f} | {r['wall_s']:.2f} | {r['speed_x']:.0f} | "
            f"{r['size_MB']:.1f} | {r['messages']} |")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m perf.bench_synth", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--profile", default="full", choices=sorted(PROFILES))
    ap.add_argument("--out", help="directory for the archive and a JSON result file")
    args = ap.parse_args(argv)
    r = run(args.profile, args.out)
    print(json.dumps(r))
    print("| profile | sim_s | wall_s | speed_x | size_MB | messages |")
    print("|---|---|---|---|---|---|")
    print(markdown_row(r))
    if args.out:
        Path(args.out, f"bench_synth_{args.profile}.json").write_text(json.dumps(r, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
