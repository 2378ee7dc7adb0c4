"""Fleet workers from the command line (docs/fleet.md).

    radical node --fleet NAME --connect EP [--vehicle V ...] [--roster FILE] [--workers N]
                 [--discover [TOPIC]] [--checkpoint-every S] [--config PARAMS.toml] [--packets PACKETS.toml]
    radical fleet status --fleet NAME [--connect EP] [--json]
    radical fleet add V [V ...] --fleet NAME [--connect EP] [--timeout S]
    radical fleet remove V [V ...] --fleet NAME [--connect EP] [--timeout S]

``radical node --fleet NAME`` runs fleet workers instead of one node: each serves the vehicles
of the roster (``--vehicle``, and/or ``--roster FILE`` with one name per line, ``#`` comments)
that it owns among the live workers, as a Zenoh client of the router at ``--connect``.
``--workers N`` starts N worker processes (default: one per CPU core); each is a ``radical node
--fleet NAME --workers 1`` of its own. ``--checkpoint-every`` (default 10 s here) sets how much
calibration progress a crash can lose. ``radical fleet status`` asks every live worker and
prints one line per worker and per vehicle: owner, mode, input lag, last checkpoint, and the
roster (each name static, added or discovered). ``radical fleet add/remove`` edits the roster the
workers share and waits until every live worker holds the edit (exit 0; 1: no worker answered or
not confirmed in time; 2: bad options). ``--discover [TOPIC]`` (off by default) lets the fleet
add the vehicles whose inputs appear on ``radical/<V>/TOPIC`` (default siru).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from radical_rt.io import zauth, zconfig

log = logging.getLogger("radical.fleet")
#: the subcommand's line in `radical --help`
HELP = "fleet status, add, remove: workers, roster, owners, lag, checkpoints"
#: Zenoh lease of a worker's link [ms]: a worker that hangs is declared dead after it
LEASE_MS = 3000


def read_roster(path: str | None, vehicles: list[str] | None, empty_ok: bool = False) -> list[str]:
    """The static roster: ``--vehicle`` names and the lines of ``--roster FILE`` (ValueError if
    unreadable, with a bad name, or empty unless ``empty_ok``: a worker may join a fleet whose
    roster the other workers hold, or that discovers its vehicles)."""
    from radical_rt.apps.node_vehicle import VEHICLE_RE

    names = list(vehicles or [])
    if path:
        try:
            lines = Path(path).read_text().splitlines()
        except OSError as exc:
            raise ValueError(f"--roster {path}: {exc.strerror or exc}") from None
        names += [ln.split("#", 1)[0].strip() for ln in lines]
    names = [n for n in names if n]
    bad = [n for n in names if not VEHICLE_RE.match(n)]
    if bad:
        raise ValueError(f"roster: vehicle names must match [a-z0-9_-]+: {bad[:5]}")
    if not names and not empty_ok:
        raise ValueError("a fleet needs vehicles: --vehicle V and/or --roster FILE")
    return sorted(set(names))


def _children(argv: list[str], n: int) -> int:
    """Start ``n`` single-worker processes with the same options; forward SIGINT/SIGTERM; the
    exit status is the worst of theirs."""
    base = [a for a in argv]
    if "--workers" in base:
        i = base.index("--workers")
        del base[i:i + 2]
    procs = [subprocess.Popen([sys.executable, "-m", "radical_rt.apps.cli", *base, "--workers", "1"])
             for _ in range(n)]

    def forward(signum: int, _frame: Any) -> None:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signum)

    old = {s: signal.signal(s, forward) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        return max(p.wait() for p in procs)
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def run_fleet(args: argparse.Namespace, argv: list[str] | None = None) -> int:
    """``radical node --fleet NAME``: N worker processes, or this process as one worker."""
    from radical_rt.apps.fleet_worker import FleetWorker
    from radical_rt.apps.node_setup import build_processors, warm_up
    from radical_rt.io.zenoh_transport import ZenohTransport

    workers = args.workers if args.workers is not None else (os.cpu_count() or 1)
    try:
        roster = read_roster(args.roster, args.vehicle, empty_ok=True)
        if args.resume or args.checkpoint:
            raise ValueError("a fleet keeps its checkpoints in the fleet's replica: "
                             "--resume/--checkpoint do not apply")
        if not args.connect:
            raise ValueError("a fleet worker connects to a router: give --connect EP "
                             "(radical router)")
        if workers < 1:
            raise ValueError("--workers must be ≥ 1")
        build_processors([roster[0] if roster else "check"], args.config, args.packets, args.clock)  # options valid?
        sa = zauth.from_args(args, "node")
    except Exception as exc:  # ValueError, ParamError, PacketError, AuthError: one line
        print(f"radical node: {exc}", file=sys.stderr)
        return 2
    if workers > 1:
        return _children(list(argv if argv is not None else sys.argv[1:]), workers)
    log.info("Numba kernels ready in %.2f s", warm_up(args.clock))
    sys.setswitchinterval(args.gil_switch_ms * 1e-3)  # (radical node --gil-switch-ms)
    extra: dict[str, Any] = {"transport/link/tx/lease": LEASE_MS}
    if sa is not None:
        extra.update(sa.settings(listening=False))
    try:
        transport = ZenohTransport("client", [], [args.connect], config_file=args.zenoh_config,
                                   extra=extra)
    except Exception as exc:
        print(f"radical node: {exc}", file=sys.stderr)
        return 1

    def make(name: str):
        return build_processors([name], args.config, args.packets, args.clock)[name]

    if not roster:
        log.info("fleet %s: no static roster: vehicles come from the fleet's shared roster "
                 "(radical fleet add)%s", args.fleet, " and discovery" if args.discover else "")
    worker = FleetWorker(transport, args.fleet, roster, make, discover=args.discover,
                         checkpoint_every_s=args.checkpoint_every or 10.0,
                         node_kw={"block_outputs": args.block_outputs,
                                  "auth": sa.profile if sa is not None else None,
                                  "stale_after_s": args.stale_after or None,
                                  "idle_release_s": args.idle_release or None,
                                  "timing": _timing(args)})
    serve_status(transport, worker)
    stop = threading.Event()
    old = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        worker.start()
        log.info("fleet %s: worker %s ready", args.fleet, worker.id)
        stop.wait(args.duration) if args.duration else stop.wait()
    finally:
        worker.stop()
        transport.close()
        timing = worker.node_kw.get("timing")
        if timing is not None:
            try:
                timing.save(args.timing_out)
            except OSError as exc:
                log.error("cannot write --timing-out %s: %s", args.timing_out, exc)
        for s, h in old.items():
            signal.signal(s, h)
    return 0


def _timing(args: argparse.Namespace) -> Any:
    """The filter loop's per-message timing records (``--timing-out``; perf/), or None."""
    if not getattr(args, "timing_out", None):
        return None
    from radical_rt.apps.node_timing import LoopTiming
    timing = LoopTiming([])
    timing.watch_gc()
    return timing


def serve_status(transport: Any, worker: Any) -> None:
    """Answer ``radical-fleet/<fleet>/status/<worker>`` with the worker's status (msgpack)."""
    import msgpack

    def status(_payload: bytes) -> bytes:
        st = worker.status()
        st["vehicles"] = {}
        for v in sorted(worker.serving):
            veh = worker.node.vehicle(v) if worker.node is not None else None
            if veh is None:  # let go meanwhile
                continue
            info = veh.node_info()
            last_in = veh.last_input_mono
            st["vehicles"][v] = {
                "mode": veh.sp.engine.mode, "flags": int(veh.sp.flags), "t": float(veh.sp.engine.t),
                "input_lag_s": time.monotonic() - last_in if last_in else None,
                "received": sum(info["received"].values()),
                "last_checkpoint_age_s": info["last_checkpoint_age_s"], "fleet": veh.fleet_info}
        return msgpack.packb(st, use_bin_type=True, default=str)

    transport.queryable(worker.prefix + f"status/{worker.id}", status)


# ----------------------------------------------------------------------------- radical fleet
def add_arguments(p: argparse.ArgumentParser) -> None:
    from radical_rt.apps.fleet_roster_cli import add_edit_parsers

    sub = p.add_subparsers(dest="fleet_cmd", metavar="{status,add,remove}")
    st = sub.add_parser("status", help="workers, vehicles, owners, input lag, last checkpoint")
    st.add_argument("--fleet", required=True, metavar="NAME")
    st.add_argument("--connect", metavar="EP", default="tcp/127.0.0.1:7447",
                    help="a router of the fleet (default tcp/127.0.0.1:7447)")
    st.add_argument("--timeout", type=float, default=3.0, metavar="S")
    st.add_argument("--json", action="store_true", help="print the workers' answers as JSON")
    zauth.add_auth_arguments(st, "monitor")
    add_edit_parsers(sub)


def open_session(args: argparse.Namespace, role: str) -> Any:
    """The tool's client session to ``--connect`` under ``--auth`` (default ``role``);
    zconfig.ZenohConfigError or zauth.AuthError for bad options."""
    from radical_rt.io.zenoh_transport import ZenohTransport

    zconfig.check_endpoint(args.connect)
    sa = zauth.from_args(args, role)
    return ZenohTransport("client", [], [args.connect],
                          extra=sa.settings(listening=False) if sa else None)


def tool_session(args: argparse.Namespace, role: str, cmd: str) -> tuple[Any, int]:
    """:func:`open_session` for a command-line tool: (session, 0), or (None, exit code) after
    printing why (2: bad options, 1: no session)."""
    from radical_rt.io.transport import TransportError

    try:
        return open_session(args, role), 0
    except (zconfig.ZenohConfigError, zauth.AuthError) as exc:
        print(f"{cmd}: error: {exc}", file=sys.stderr)
        return None, 2
    except TransportError as exc:
        print(f"{cmd}: {exc}", file=sys.stderr)
        return None, 1


def run(args: argparse.Namespace) -> int:
    import msgpack

    from radical_rt.apps.fleet_roster_cli import print_roster, run_edit

    if args.fleet_cmd in ("add", "remove"):
        return run_edit(args)
    if args.fleet_cmd != "status":
        print("radical fleet: give a subcommand: status, add or remove", file=sys.stderr)
        return 2
    t, rc = tool_session(args, "monitor", "radical fleet")
    if t is None:
        return rc
    try:
        replies = t.get(f"radical-fleet/{args.fleet}/status/*", b"", timeout=args.timeout,
                        every=True)
    finally:
        t.close()
    workers = sorted((msgpack.unpackb(r, raw=False) for r in replies), key=lambda w: w["worker"])
    if args.json:
        print(json.dumps(workers, indent=2, default=str))
        return 0 if workers else 1
    if not workers:
        print(f"fleet {args.fleet}: no worker answered at {args.connect}", file=sys.stderr)
        return 1
    print(f"fleet {args.fleet}: {len(workers)} worker(s)")
    for w in workers:
        print(f"  worker {w['worker']}: serving {len(w['serving'])}, takeovers "
              f"{len(w['takeovers'])}{', FENCED (no router)' if w['fenced'] else ''}")
    print(f"  {'vehicle':<16} {'worker':<28} {'mode':<11} {'lag s':>7} {'ckpt age s':>10} lost s")
    for w in workers:
        for v, d in sorted(w["vehicles"].items()):
            lag, age = d["input_lag_s"], d["last_checkpoint_age_s"]
            lost = (d.get("fleet") or {}).get("lost_s")
            print(f"  {v:<16} {w['worker']:<28} {d['mode']:<11} "
                  f"{'-' if lag is None else f'{lag:7.2f}':>7} "
                  f"{'-' if age is None else f'{age:10.1f}':>10} {'-' if lost is None else f'{lost:.1f}'}")
    print_roster(workers)
    return 0
