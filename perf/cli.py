"""Run the benchmark suite: `radical bench [--profile smoke|quick|full] [--only NAME ...] [--out DIR]`.

Each benchmark module exposes ``run(profile, out_dir) -> dict`` and writes ``DIR/<name>_<profile>.json``;
this command runs them in turn and writes ``DIR/summary_<profile>.json`` and ``DIR/summary_<profile>.md``.
The live benchmarks (startup, latency, capacity; real Zenoh on loopback, see perf/README.md) also
return regression checks (ratios measured in the same run); the exit code is 1 if a benchmark
failed or a check did not pass.
"""

from __future__ import annotations

import argparse
import importlib
import json
import sys
from pathlib import Path

from radical_rt.io.outpaths import output_dir

BENCHES = {"kernels": "perf.bench_kernels", "synth": "perf.bench_synth", "engine": "perf.bench_engine",
           "clock": "perf.bench_clock", "fdi": "perf.bench_fdi_bank", "startup": "perf.bench_startup",
           "latency": "perf.bench_latency", "capacity": "perf.bench_capacity",
           "fleet": "perf.bench_fleet", "fleet_capacity": "perf.bench_fleet_capacity",
           "router": "perf.bench_router"}
DEFAULT_OUT = Path(__file__).resolve().parent / "results"


#: the subcommand's line in `radical --help`
HELP = "run the benchmark suite"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--profile", default="quick", choices=("smoke", "quick", "full"))
    p.add_argument("--only", nargs="*", choices=list(BENCHES), help="run only these benchmarks")
    p.add_argument("--out", default=str(DEFAULT_OUT), type=output_dir, help="result directory")


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results, failed = {}, []
    for name in args.only or list(BENCHES):
        try:
            mod = importlib.import_module(BENCHES[name])
        except ImportError as exc:
            print(f"bench {name}: not available ({exc})", file=sys.stderr)
            continue
        print(f"bench {name} ({args.profile}) ...", file=sys.stderr, flush=True)
        try:
            results[name] = mod.run(args.profile, out)
        except Exception as exc:  # a broken benchmark must not hide the others' figures
            failed.append(name)
            print(f"bench {name}: FAILED: {exc!r}", file=sys.stderr)
    bad_checks = [f"{name}: {c.get('name')}" for name, res in results.items() if isinstance(res, dict)
                  for c in res.get("checks") or [] if isinstance(c, dict) and c.get("ok") is False]
    (out / f"summary_{args.profile}.json").write_text(json.dumps(results, indent=1, default=str))
    lines = [f"# radical bench ({args.profile})", ""]
    for name, res in results.items():
        md = getattr(importlib.import_module(BENCHES[name]), "markdown", None)
        lines += [f"## {name}", "", md(res) if md else "```\n" + json.dumps(res, indent=1, default=str) + "\n```", ""]
    (out / f"summary_{args.profile}.md").write_text("\n".join(lines))
    print("\n".join(lines))
    for line in bad_checks:
        print(f"bench check FAILED: {line}", file=sys.stderr)
    return 1 if failed or bad_checks else 0
