"""Covariance analysis of a calibration maneuver before it is flown (no data needed).

    radical design SCENARIO|MANEUVER.toml [--warm [PRIOR]] [--json FILE] [--target-scale F]

SCENARIO is a built-in name or a scenario TOML (the format `radical synth` runs; only its
[maneuver], [trackers] and [siru] clock keys matter). The engine's own models and UD kernels run
on the planned attitude history with noise-free measurements (docs/design.md): the predicted σ of
every parameter group over time, the time to reach the target σ (default: the paper's final σ of
2006216, messenger_tables.json), and the most poorly determined directions of the parameter space.
--warm continues after a cold design of PRIOR (default 2006216) and the §3.1 warm start + bump.

examples:
  radical design 2006216
  radical design my_maneuver.toml --json out/my_design.json
  radical design my_maneuver.toml --warm --target-scale 1.5
  radical design --optimize --out best.toml           # shortest maneuver of the family
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from tqdm import tqdm

from mission.design import analysis
from radical_rt.contract.params import ParamError, ParamTable
from radical_rt.io.outpaths import output_file

#: the subcommand's line in `radical --help`
HELP = "covariance analysis and optimization of a calibration maneuver"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", nargs="?", metavar="SCENARIO", help="built-in name or TOML file")
    p.add_argument("--duration", type=float, metavar="S", help="override the scenario's length")
    p.add_argument("--warm", nargs="?", const="2006216", metavar="PRIOR",
                   help="after a warm start + bump following PRIOR (default 2006216)")
    p.add_argument("--config", metavar="PARAMS.toml", help="engine parameter overrides")
    p.add_argument("--json", metavar="FILE", type=output_file, help="write the predicted σ and histories here")
    p.add_argument("--target-scale", type=float, default=1.0, metavar="F",
                   help="targets = F × the paper's final σ (default 1)")
    p.add_argument("--record-dt", type=float, default=10.0, metavar="S",
                   help="σ history step (default 10 s)")
    p.add_argument("--sun-axis", default="y", choices=("x", "y", "z"),
                   help="body axis kept near the Sun (default y)")
    p.add_argument("--sun-max-deg", type=float, default=float("inf"),
                   help="largest allowed Sun angle of that axis (default: unconstrained)")
    p.add_argument("--exclusion-deg", type=float, default=0.0,
                   help="trackers' Sun exclusion half-cone; blinded samples are dropped")
    p.add_argument("--optimize", action="store_true",
                   help="search the maneuver family for the shortest one meeting the targets")
    p.add_argument("--out", metavar="BEST.toml", type=output_file, help="--optimize: write the best maneuver here")
    p.add_argument("--max-duration", type=float, default=7200.0, metavar="S",
                   help="--optimize: longest acceptable maneuver (default 7200 s)")
    p.add_argument("--groups", metavar="G1,G2", help="--optimize: only these groups' targets "
                   "(e.g. b,lam,mu,du,dv)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _fail(msg: str) -> int:
    print(f"radical design: error: {msg}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    from mission.design import plan as planmod
    from mission.design.constraints import Pointing, check  # (scipy only when the command runs)
    from replayer.synth.schema import ScenarioError

    if args.target_scale <= 0 or args.record_dt <= 0:
        return _fail("--target-scale and --record-dt must be > 0")
    try:
        table = ParamTable.from_toml(args.config) if args.config else None
        targets = analysis.scale_targets(analysis.paper_targets(planmod.tables()),
                                         args.target_scale)
        pointing = Pointing(args.sun_axis, 1.0, args.sun_max_deg, args.exclusion_deg)
        if args.optimize:
            from mission.design.optimize import run_cli
            from radical_rt.contract.state import PARAM_GROUPS
            bad = set((args.groups or "b").split(",")) - set(PARAM_GROUPS)
            if bad:
                return _fail(f"--groups: unknown {', '.join(sorted(bad))}; "
                             f"groups: {','.join(PARAM_GROUPS)}")
            return run_cli(args, table, targets, pointing)
        if not args.scenario:
            return _fail("a SCENARIO (built-in name or TOML file) is required")
        sc = planmod.load(args.scenario, duration=args.duration)
    except (ScenarioError, ParamError) as exc:
        return _fail(str(exc).splitlines()[0])
    bar = tqdm(total=100, disable=args.quiet, file=sys.stderr, desc="design", unit="%")

    def prog(f):
        bar.n = int(100 * f)
        bar.refresh()

    engine = None
    if args.warm:
        try:
            engine, _ = planmod.warm_engine(args.warm, table, progress=prog)
        except ScenarioError as exc:
            bar.close()
            return _fail(f"--warm {args.warm}: {str(exc).splitlines()[0]}")
        bar.n = 0
    hist, plan = planmod.design(sc, table, engine, args.record_dt, pointing, progress=prog)
    bar.close()
    geo = (engine.geo if engine else None) or _geometry()
    point = check(plan.trajectory, plan.t0, plan.duration_s,
                  sc.cfg["maneuver"]["q0_body_from_inertial"], pointing, geo)
    s = analysis.design_summary(sc.name, hist, targets, extra={
        "start": "warm" if args.warm else "cold", "pointing": point,
        "counters": {k: int(v) for k, v in hist.counters.items()}})
    print(analysis.format_report(s))
    print(f"  pointing: {args.sun_axis} axis ≤ {point['sun_axis_max_deg']:.1f}° from the Sun; "
          f"tracker Sun angles ≥ {point['st1_sun_min_deg']:.1f}° / "
          f"{point['st2_sun_min_deg']:.1f}°; {'ok' if point['ok'] else 'VIOLATED'}")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(s) + "\n")
    return 0


def _geometry():
    from radical_rt.contract.geometry import Geometry
    return Geometry()
