"""Publish an archive's input channels over Zenoh, paced by their bus time (`radical replay`).

The input channels of each archive (``/siru``, ``/st1``, ``/st2``, ``/temp``; CONTRACT §4) are
published on ``radical/<vehicle>/<topic>`` (§2) in log_time order with the MCAP payloads unchanged
(the msgpack bytes as stored). Pacing uses absolute deadlines on ``time.monotonic``: message i is
due at ``wall_0 + (log_time_i − log_time_0) / rate``, so a late message never shifts the ones
after it (no drift). ``--fast`` publishes as fast as the subscribers keep up: every publisher uses
``CongestionControl.BLOCK`` (always, not only with ``--fast``), so a slow subscriber slows the
replay down instead of losing samples.

Several archives are replayed in sequence as disjoint streams: each keeps its own time line, the
first message of the next archive is due when the previous archive's last one was (plus ``--gap``
wall seconds). ``--start``/``--end`` are seconds relative to each archive's start (its first
message on any channel), the window is [start, end).

Examples::

    radical replay run.mcap --vehicle messenger                  # real time, to the default node
    radical replay run.mcap --vehicle messenger --rate 10 --wait-node 30
    radical replay a.mcap b.mcap --vehicle messenger --fast --connect tcp/127.0.0.1:7448
    radical replay run.mcap --vehicle messenger --start 600 --end 1200 --no-progress

Sessions: with ``--connect`` only (or neither option: the node's default endpoint) the replayer
is a Zenoh client of that endpoint (the node, a peer, routes between its clients, e.g. to a
connected ``radical record``); with ``--listen`` it is a peer. A client cannot open before its
endpoint is up: it fails at once, or retries for the ``--wait-node``/``--wait-subscribers`` time.

Each archive ends with an end-of-stream marker on ``radical/<vehicle>/eos`` (docs/replay_record.md)
that carries the messages sent per topic; messages put while a publisher had no matching
subscriber, or whose put failed, are reported as not delivered.

A node serving ``--vehicle`` is required: replay waits up to ``--wait-node`` (default 10 s) for
its liveliness token ``radical/<vehicle>/alive/filter`` and fails with exit status 1, naming the
vehicles the nodes there do serve, if none appears. ``--no-wait-node`` (or ``--wait-subscribers``,
e.g. for a recorder alone) publishes without that check.

Exit status: 0 done, 1 run-time failure (no node within the timeout, Zenoh error), 2 bad input
(missing or unreadable archive, no input channel, bad option), 3 done but some messages were
not delivered, 130 interrupted.

This module is the command line; the publication is :mod:`replayer.publish`, the Zenoh sessions
and the node's liveliness :mod:`replayer.sessions`.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import signal
import sys
import threading
import time
import warnings
from typing import Any

from radical_rt.io import zauth
from radical_rt.io.archive import ArchiveError, TruncatedArchiveWarning
from replayer.publish import check_inputs, replay
from replayer.sessions import (
    ReplayError,
    check_vehicle,
    node_token_key,
    open_session,
    served_vehicles,
    tool_config,
    wait_for_node,
)

DEFAULT_WAIT_S = 10.0
SETTLE_S = 1.0  # longest wait for the subscribers of a node already seen (then publish anyway)


# -------------------------------------------------------------------------------------- CLI
def _wait_arg(text: str) -> float:
    v = float(text)
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"timeout must be > 0 s, got {text!r}")
    return v


def _rate_arg(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid rate {text!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"rate must be > 0, got {text!r}")
    return v


#: the subcommand's line in `radical --help`
HELP = "publish an archive's input channels over Zenoh"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("inputs", nargs="+", metavar="IN.mcap",
                   help="archive(s), replayed in sequence as disjoint streams")
    p.add_argument("--vehicle", required=True, help="vehicle name ([a-z0-9_-]+): keys "
                   "radical/<vehicle>/{siru,st1,st2,temp}")
    pace = p.add_mutually_exclusive_group()
    pace.add_argument("--rate", type=_rate_arg, default=1.0, metavar="X",
                      help="archive seconds per wall second (default 1: real time)")
    pace.add_argument("--fast", action="store_true",
                      help="as fast as the subscribers keep up (no sample dropped)")
    p.add_argument("--start", type=float, default=None, metavar="S",
                   help="start S seconds after each archive's start")
    p.add_argument("--end", type=float, default=None, metavar="S",
                   help="stop S seconds after each archive's start (exclusive)")
    p.add_argument("--gap", type=float, default=0.0, metavar="S",
                   help="wall seconds between two archives (default 0)")
    p.add_argument("--listen", metavar="EP", help="listen on EP (tcp/127.0.0.1:PORT)")
    p.add_argument("--connect", metavar="EP", help="connect to EP (default: the node's "
                   "default endpoint tcp/127.0.0.1:7448)")
    p.add_argument("--zenoh-config", metavar="FILE",
                   help="Zenoh JSON5 file loaded first (endpoints and scouting still enforced)")
    zauth.add_auth_arguments(p, "sensor")
    p.add_argument("--wait-node", nargs="?", type=_wait_arg, const=DEFAULT_WAIT_S, default=None,
                   metavar="TIMEOUT", help="wait up to TIMEOUT (default 10 s) for the node's "
                   "liveliness token and for subscribers on every published key before starting. "
                   "Without this option replay still requires a node serving --vehicle: it waits "
                   "up to 10 s for its token and fails (exit 1) if none appears")
    p.add_argument("--no-wait-node", action="store_true",
                   help="publish without checking that a node serves --vehicle (e.g. to a "
                        "recorder only; --wait-subscribers also skips the check)")
    p.add_argument("--wait-subscribers", nargs="?", type=_wait_arg, const=DEFAULT_WAIT_S,
                   default=None, metavar="TIMEOUT", help="wait (default 10 s) for subscribers on "
                   "every published key (e.g. a recorder), without requiring a node")
    p.add_argument("--linger", type=float, default=2.0, metavar="S",
                   help="keep the session open S seconds after the last message so queued "
                        "messages are delivered (default 2)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.add_argument("--json", action="store_true", help="print the result as JSON on stdout")


def _err(msg: str) -> None:
    print(f"radical replay: error: {' '.join(str(msg).split())}", file=sys.stderr)


def _summary_line(res: dict[str, Any]) -> str:
    per = ", ".join(f"{t.lstrip('/')} {n}" for t, n in res["counts"].items())
    rate = res["achieved_rate"]
    text = (f"replayed {res['messages']} messages ({per}) from {len(res['files'])} archive(s): "
            f"{res['archive_s']:.2f} s of archive in {res['wall_s']:.2f} s"
            + (f" ({rate:.2f}x)" if rate else ""))
    pc = res["pacing"]
    if pc:
        text += (f"; pacing error p50 {pc['p50_s'] * 1e3:.3f} ms, p99 {pc['p99_s'] * 1e3:.3f} ms, "
                 f"max {pc['max_s'] * 1e3:.3f} ms")
    nd = res.get("not_delivered", 0)
    if nd:
        lost = {t.lstrip("/"): res["unmatched"][t] + res["failed"][t] for t in res["unmatched"]
                if res["unmatched"][t] + res["failed"][t]}
        text += f"; NOT DELIVERED {nd} ({lost}: no subscriber or failed put)"
    return text + (" (stopped early)" if res["stopped"] else "")


def run(args: argparse.Namespace) -> int:
    import zenoh

    from radical_rt.io import zconfig

    # archive warnings are printed here as one line each, not by logging's last-resort handler
    archive_log = logging.getLogger("radical_rt.io.archive")
    if not any(isinstance(h, logging.NullHandler) for h in archive_log.handlers):
        archive_log.addHandler(logging.NullHandler())
    try:
        check_vehicle(args.vehicle)
        sources, notes = check_inputs(args.inputs, args.start, args.end)
        if not (math.isfinite(args.gap) and args.gap >= 0):
            raise ReplayError(f"--gap must be >= 0 s, got {args.gap!r}")
        cfg, mode, where = tool_config(args.listen, args.connect, "replay", args.zenoh_config,
                                       auth=zauth.from_args(args, "sensor"))
    except (ReplayError, ArchiveError, zconfig.ZenohConfigError, zauth.AuthError) as e:
        _err(str(e))
        return 2
    except Exception as e:  # e.g. an unreadable --zenoh-config file
        _err(f"{type(e).__name__}: {e}")
        return 2
    for n in notes:
        print(f"radical replay: warning: {n}", file=sys.stderr)

    stop = threading.Event()
    old = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, lambda *_: stop.set())
    hint = f"is `radical node --vehicle {args.vehicle}` running there?"
    # a node serving the vehicle is required unless told otherwise (bounded default wait)
    node_wait = args.wait_node
    if node_wait is None and not args.no_wait_node and args.wait_subscribers is None:
        node_wait = DEFAULT_WAIT_S
    try:
        zenoh.try_init_log_from_env()
        t_start = time.monotonic()
        wait_s = max(args.wait_node or 0.0, args.wait_subscribers or 0.0)
        try:
            session = open_session(cfg, mode, t_start + wait_s if wait_s else None, stop)
        except ReplayError as e:
            if stop.is_set():
                print("radical replay: interrupted", file=sys.stderr)
                return 130
            within = f" within {wait_s:g} s" if wait_s else ""
            _err(f"{e} ({where}{within}); {hint}")
            return 1
        try:
            if node_wait is not None:
                left = max(t_start + node_wait - time.monotonic(), 0.1)
                try:
                    wait_for_node(session, args.vehicle, left, stop)
                except ReplayError:
                    if stop.is_set():
                        print("radical replay: interrupted", file=sys.stderr)
                        return 130
                    others = served_vehicles(session)
                    seen = (f"; nodes there serve: {', '.join(others)}" if others
                            else "; no node seen there")
                    _err(f"no filter node for vehicle {args.vehicle!r}: liveliness token "
                         f"{node_token_key(args.vehicle)} not seen within {node_wait:g} s "
                         f"({where}){seen}; {hint} (--no-wait-node publishes anyway)")
                    return 1
                waited = time.monotonic() - t_start
                print(f"radical replay: node {node_token_key(args.vehicle)} alive "
                      f"(waited {waited:.2f} s)", file=sys.stderr)
            # the node is there: give its subscriber routes a moment to arrive
            wait_subs, settle = None, (SETTLE_S if node_wait is not None else 0.0)
            if wait_s:
                wait_subs = max(t_start + wait_s - time.monotonic(), 0.1)
            try:
                with warnings.catch_warnings():  # already reported above
                    warnings.simplefilter("ignore", TruncatedArchiveWarning)
                    res = replay([s.path for s in sources], args.vehicle, session,
                                 rate=None if args.fast else args.rate, start=args.start,
                                 end=args.end, progress=not args.no_progress,
                                 wait_subscribers=wait_subs, settle=settle, gap=args.gap,
                                 stop_event=stop)
            except ReplayError as e:
                if stop.is_set():
                    print("radical replay: interrupted", file=sys.stderr)
                    return 130
                _err(f"{e} ({where})")
                return 1
            except ArchiveError as e:
                _err(str(e))
                return 2
        finally:
            # Zenoh has no flush: keep the session open so that messages still queued in this
            # process's transmit queue reach the subscribers before the links close.
            time.sleep(max(args.linger, 0.0))
            session.close()
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)
    print(f"radical replay: {_summary_line(res)}", file=sys.stderr)
    if args.json:
        print(json.dumps(res, sort_keys=True))
    if res["stopped"]:
        return 130
    return 3 if res.get("not_delivered") else 0
