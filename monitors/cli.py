"""Live dashboards over Zenoh: ``radical monitor tui|web|foxglove``.

    radical monitor tui [--vehicle V] [--listen EP | --connect EP] [--refresh S] [--stale-s S]
    radical monitor web [--vehicle V] [--port P] [--listen EP | --connect EP] [--stale-s S]
    radical monitor foxglove --vehicle V [--port P] [--listen EP | --connect EP]

Both subscribe to ``radical/<V>/tlm/*``, ``fault``, ``diag`` (all vehicles when --vehicle is not
given; the first one seen is shown) and the liveliness tokens ``radical/<V>/alive/filter``. With
neither --listen nor --connect they connect to the node's default endpoint
(``tcp/127.0.0.1:7448``). Endpoints must be loopback locators; multicast scouting is off. The web
server binds 127.0.0.1 only. Exit status 0, 1 on a Zenoh or server failure, 2 on a bad option or
a missing optional package (textual for tui, bokeh for web, foxglove-sdk for foxglove). The
foxglove bridge (monitors/fox_live.py) is a Foxglove WebSocket server on 127.0.0.1 for the
Foxglove app or Lichtblick.
"""

from __future__ import annotations

import argparse
import sys

from monitors.common import VEHICLE_RE
from monitors.view import STALE_S
from radical_rt.io import zauth


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--vehicle", metavar="V", help="vehicle to show ([a-z0-9_-]+; default: first seen)")
    p.add_argument("--listen", metavar="EP", help="listen on a loopback endpoint tcp/127.0.0.1:PORT")
    p.add_argument("--connect", metavar="EP",
                   help="connect to a loopback endpoint (default tcp/127.0.0.1:7448, the node's)")
    p.add_argument("--zenoh-config", metavar="FILE", help="Zenoh JSON5 file loaded first "
                   "(loopback endpoints and multicast off are still enforced)")
    zauth.add_auth_arguments(p, "monitor")


def _stale(p: argparse.ArgumentParser) -> None:
    p.add_argument("--stale-s", type=float, default=STALE_S, metavar="S",
                   help=f"stale-data alarm after S seconds without a packet of the vehicle "
                        f"(receiver clock; default {STALE_S:g})")


#: the subcommand's line in `radical --help`
HELP = "live dashboards (web, tui)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="monitor", metavar="{tui,web,foxglove}")
    tui = sub.add_parser("tui", help="terminal dashboard (textual)", description=(
        "Terminal dashboard of a running node: attitude, mode and flags, parameter estimates "
        "± 1σ, residuals and the SIRU clock, from radical/<V>/tlm/*, fault and diag and the "
        "node's liveliness token. Needs the optional package textual. With neither --listen nor "
        "--connect it connects to the node's default endpoint tcp/127.0.0.1:7448."))
    _common(tui)
    tui.add_argument("--refresh", type=float, default=0.5, metavar="S",
                     help="screen refresh period in seconds (default 0.5)")
    _stale(tui)
    web = sub.add_parser("web", help="web dashboard (Bokeh server on 127.0.0.1)", description=(
        "Web dashboard of a running node: a Bokeh server bound to 127.0.0.1 (--port) plotting "
        "attitude, estimates ± 1σ, residuals, flags and the SIRU clock from radical/<V>/tlm/*, "
        "fault and diag. Needs the optional package bokeh. With neither --listen nor --connect "
        "it connects to the node's default endpoint tcp/127.0.0.1:7448."))
    _common(web)
    web.add_argument("--port", type=int, default=5006, help="HTTP port on 127.0.0.1 (default 5006)")
    web.add_argument("--period-ms", type=int, default=250,
                     help="browser update period in ms (default 250 = 4 Hz)")
    web.add_argument("--keep", type=int, default=3600,
                     help="tlm/large packets kept per vehicle in the plots (default 3600)")
    _stale(web)
    fox = sub.add_parser("foxglove", help="Foxglove WebSocket server on 127.0.0.1 (foxglove-sdk)",
                         description=("Foxglove WebSocket server on 127.0.0.1 republishing a "
                                      "node's outputs for the Foxglove app or Lichtblick. Needs "
                                      "the optional package foxglove-sdk."))
    _common(fox)
    fox.add_argument("--port", type=int, default=8765,
                     help="WebSocket port on 127.0.0.1 (default 8765; 0 = any free port)")
    fox.add_argument("--duration", type=float, default=None, metavar="S",
                     help="stop after S seconds (default: until SIGINT/SIGTERM)")


def _err(msg: str) -> int:
    print(f"radical monitor: {msg}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    kind = getattr(args, "monitor", None)
    if kind not in ("tui", "web", "foxglove"):
        return _err("choose a dashboard: radical monitor tui | web | foxglove")
    if args.vehicle is not None and not VEHICLE_RE.match(args.vehicle):
        return _err(f"--vehicle {args.vehicle!r} must match [a-z0-9_-]+")
    from radical_rt.io import zconfig

    try:
        for ep in (args.listen, args.connect):
            if ep is not None:
                zconfig.check_endpoint(ep)
        args.session_auth = zauth.from_args(args, "monitor")
    except (zconfig.ZenohConfigError, zauth.AuthError) as e:
        return _err(str(e))
    if kind != "foxglove" and not args.stale_s > 0:
        return _err("--stale-s must be > 0")
    if kind == "tui":
        try:
            from monitors.tui import run_tui
        except ImportError as e:
            return _err(f"the tui needs textual (pip install textual): {e}")
        try:
            return run_tui(args.vehicle, args.listen, args.connect, args.zenoh_config, args.refresh,
                           args.stale_s, auth=args.session_auth)
        except Exception as e:  # zenoh session failures
            print(f"radical monitor tui: {type(e).__name__}: {e}", file=sys.stderr)
            return 1
    if kind == "foxglove":
        return _run_foxglove(args)
    if not (0 < args.port < 65536):
        return _err(f"--port {args.port} out of range")
    if args.period_ms < 50 or args.period_ms > 500:
        return _err("--period-ms must be within 50..500 (≥ 2 Hz updates)")
    try:
        from monitors.web import serve
    except ImportError as e:
        return _err(f"the web dashboard needs bokeh (pip install bokeh): {e}")
    from monitors.live import LatestStore, ZenohSource

    store = LatestStore()
    try:
        source = ZenohSource(store, None, args.listen, args.connect, args.zenoh_config,
                             auth=args.session_auth).start()
    except Exception as e:
        print(f"radical monitor web: cannot open Zenoh session: {type(e).__name__}: {e}",
              file=sys.stderr)
        return 1
    try:
        return serve(store, args.vehicle, args.port, source=source, period_ms=args.period_ms,
                     keep=args.keep, stale_s=args.stale_s)
    except OSError as e:
        source.close()
        print(f"radical monitor web: cannot serve on 127.0.0.1:{args.port}: {e}", file=sys.stderr)
        return 1


def _run_foxglove(args: argparse.Namespace) -> int:
    if args.vehicle is None:
        return _err("radical monitor foxglove needs --vehicle V")
    if not (0 <= args.port < 65536):
        return _err(f"--port {args.port} out of range")
    if args.duration is not None and args.duration <= 0:
        return _err("--duration must be > 0")
    try:
        from monitors.fox_live import serve as serve_foxglove
    except ImportError as e:
        return _err(f"the foxglove bridge needs foxglove-sdk (pip install foxglove-sdk): {e}")
    return serve_foxglove(args.vehicle, args.port, args.listen, args.connect, args.zenoh_config,
                          args.duration, auth=args.session_auth)
