"""``radical fleet add/remove V [V ...]``: edit the roster a fleet's workers share, and the
roster lines of ``radical fleet status`` (docs/fleet.md, "Roster").

An edit is published once per vehicle (:func:`radical_rt.fleet.roster_edit.edit_roster`), then
every live worker is polled until it holds it. Exit status: 0 every live worker holds the edit,
1 no worker answered (nothing published) or not every one confirmed within ``--timeout`` (or a
later edit superseded it), 2 bad options (a vehicle name must match ``[a-z0-9_-]+``).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from radical_rt.io import zauth


def add_edit_parsers(sub: Any) -> None:
    """The ``add`` and ``remove`` subcommands of ``radical fleet``."""
    for name, what in (("add", "add vehicles to the fleet's roster"),
                       ("remove", "remove vehicles from the fleet's roster (static ones too)")):
        p = sub.add_parser(name, help=what, description=f"{what}; waits until every live "
                           "worker holds the edit (exit 0), 1 if none answered or not all "
                           "confirmed in time, 2 for bad options")
        p.add_argument("vehicles", nargs="+", metavar="V", help="vehicle name [a-z0-9_-]+")
        p.add_argument("--fleet", required=True, metavar="NAME")
        p.add_argument("--connect", metavar="EP", default="tcp/127.0.0.1:7447",
                       help="a router of the fleet (default tcp/127.0.0.1:7447)")
        p.add_argument("--timeout", type=float, default=5.0, metavar="S",
                       help="how long to wait for every live worker to confirm (default 5)")
        zauth.add_auth_arguments(p, "operator")


def run_edit(args: argparse.Namespace) -> int:
    from radical_rt.apps.fleet_cli import tool_session
    from radical_rt.fleet.roster import NAME, origin_id
    from radical_rt.fleet.roster_edit import edit_roster

    cmd = f"radical fleet {args.fleet_cmd}"
    bad = [v for v in [args.fleet, *args.vehicles] if not NAME.match(v)]
    if bad or not args.timeout > 0:
        why = f"names must match [a-z0-9_-]+: {bad}" if bad else "--timeout must be > 0"
        print(f"{cmd}: error: {why}", file=sys.stderr)
        return 2
    t, rc = tool_session(args, "operator", cmd)
    if t is None:
        return rc
    try:
        res = edit_roster(t, args.fleet, args.fleet_cmd, args.vehicles, origin_id("cli"),
                          timeout=args.timeout)
    finally:
        t.close()
    if not res.edits:
        print(f"{cmd}: no worker of fleet {args.fleet} answered at {args.connect}: nothing "
              "changed", file=sys.stderr)
        return 1
    done = "added to" if res.op == "add" else "removed from"
    print(f"fleet {args.fleet}: {', '.join(res.vehicles)} {done} the roster (clock "
          f"{res.edits[0].clock}); confirmed by {len(res.acked)} of {len(res.live)} live "
          f"worker(s)")
    for v in res.unchanged:
        print(f"  {v}: " + ("already in the roster" if res.op == "add" else
                            "was not in the roster (now kept out: discovery will not add it)"))
    for v, who in sorted(res.owners.items()):
        print(f"  {v}: owner {who}")
    for v, e in sorted(res.superseded.items()):
        print(f"  {v}: superseded by a later {e.op} (clock {e.clock}, by {e.by})")
    missing = sorted(set(res.live) - set(res.acked))
    if missing:
        print(f"{cmd}: not confirmed within {args.timeout:g} s by: {', '.join(missing)}",
              file=sys.stderr)
    return 0 if res.ok else 1


def print_roster(workers: list[dict[str, Any]]) -> None:
    """The roster lines of ``radical fleet status`` (from the workers' status answers)."""
    rosters = [w["roster"] for w in workers if w.get("roster")]
    if not rosters:
        return
    sets = {tuple(r["vehicles"]) for r in rosters}
    ref = max(rosters, key=lambda r: r["clock"])
    print(f"  roster: {len(ref['vehicles'])} vehicle(s), clock {ref['clock']}"
          + ("" if len(sets) == 1 else "; WORKERS DISAGREE (edits still spreading?)"))
    for v, e in sorted(ref["entries"].items()):
        print(f"    {v:<16} {e['state']:<10} by {e['by']} (clock {e['clock']})")
    for w in workers:
        d = w.get("discovery")
        if d and d.get("active"):
            print(f"  discovery: worker {w['worker']} watches radical/*/{d['topic']} "
                  f"({d['samples']} samples, discovered {len(d['discovered'])})")
