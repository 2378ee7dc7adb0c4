"""Synthesize a MESSENGER-like telemetry archive (MCAP) from a scenario.

SCENARIO is a built-in name (2005300, 2005301, 2006216, original, alternate, static) or a TOML file
(`base = "2006216"` inherits a built-in; `radical synth --print-default [NAME]` prints the full
default scenario as TOML). See docs/scenarios.md for every key and the maneuver timelines.

examples:
  radical synth 2006216 -o out/2006216.mcap
  radical synth my.toml -o out/my.mcap --seed 7 --duration 600
  radical synth --print-default alternate > alternate.toml
"""

from __future__ import annotations

import argparse
import json
import sys

from radical_rt.io.archive import ArchiveError
from radical_rt.io.outpaths import output_file

from .schema import ScenarioError

#: the subcommand's line in `radical --help`
HELP = "synthesize a MESSENGER-like telemetry archive (MCAP)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of `radical synth`."""
    parser.add_argument("scenario", nargs="?", metavar="SCENARIO",
                        help="built-in scenario name or TOML scenario file")
    parser.add_argument("-o", "--output", metavar="OUT.mcap", type=output_file, help="output archive")
    parser.add_argument("--seed", type=int, help="override the scenario's seed")
    parser.add_argument("--duration", type=float, metavar="S", help="override the run length (s)")
    parser.add_argument("--vehicle", metavar="V", help="override the vehicle name")
    parser.add_argument("--print-default", nargs="?", const="", metavar="NAME",
                        help="print the full scenario NAME (default: SCENARIO or 2006216) as TOML "
                             "and exit")
    parser.add_argument("--quiet", action="store_true", help="no progress bar or summary line")


def _fail(msg: str) -> int:
    print(f"radical synth: error: {msg}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    """Run `radical synth`; 0 on success, 2 on a bad scenario or arguments."""
    from .api import synthesize  # (the simulator and scipy only when the command runs)
    from .scenario import print_default

    try:
        if args.print_default is not None:
            sys.stdout.write(print_default(args.print_default or args.scenario))
            return 0
        if not args.scenario:
            return _fail("a SCENARIO (built-in name or TOML file) is required")
        if not args.output:
            return _fail("an output archive is required (-o OUT.mcap)")
        res = synthesize(args.scenario, args.output, seed=args.seed, duration=args.duration,
                         progress=not args.quiet, vehicle=args.vehicle)
    except ScenarioError as exc:
        return _fail(str(exc).splitlines()[0])
    except ArchiveError as exc:
        print(f"radical synth: error: {exc}", file=sys.stderr)
        return 1
    if not args.quiet:
        summary = {"paths": [str(p) for p in res.paths], "seconds": round(res.elapsed_s, 3),
                   "bytes": res.file_size, "messages": res.message_counts,
                   "truth_counts": res.truth_counts}
        print(json.dumps(summary), file=sys.stderr)
    return 0
