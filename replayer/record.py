"""Record ``radical/<vehicle>/**`` to an MCAP archive (`radical record`).

Every sample on the vehicle's keys (inputs, telemetry, faults, diagnostics; CONTRACT §2) is
written with its payload unchanged to the channel named after its key (§4), with the contract's
JSON schema when the topic has one:

* one vehicle (``--vehicle messenger``): key ``radical/messenger/tlm/small`` → MCAP topic
  ``/tlm/small``, exactly as §4 (one file per telemetry stream; ``radical replay`` and
  ``radical process`` read it as they are);
* all vehicles (``--vehicle '*'``): key ``radical/messenger/tlm/small`` → MCAP topic
  ``/messenger/tlm/small`` (the vehicle is kept in the topic, with the schema of ``/tlm/small``
  and the channel metadata ``vehicle``). Such a file holds several streams and is for inspection,
  not for replay/process.

Liveliness (``alive/**``) and command (``cmd/**``) keys are not recorded, nor the end-of-stream
markers (``eos``, docs/replay_record.md): the recorder compares the counts a marker carries with
the messages it recorded since the previous marker of that vehicle and reports the difference as
``lost`` (messages the publisher sent that never reached the file).

log_time = publish_time = the message's bus time in ns (CONTRACT §1.2), read from the payload's
top-level ``t_bus`` or ``t`` (the last element of a columnar ``t_bus``, e.g. ``/siru``) without
decoding the rest. A message without a readable bus time gets its receive time expressed on the
bus time line (the last bus time received from that vehicle plus the wall time elapsed since it
arrived), or the UTC receive time (ns) if no bus time has been seen yet.

Subscriber callbacks only enqueue (bounded queue; a callback waits at most ``block_s`` for room,
which back-pressures BLOCK publishers such as ``radical replay``, then drops and counts); one
writer thread (the caller's) owns the MCAP writer. The file is flushed (chunk closed) every
``flush_every_s`` seconds, so a recorder killed with SIGKILL leaves a readable prefix (read it with
ArchiveReader, which warns that it is truncated, or rewrite it with ``archive.recover``).
SIGINT/SIGTERM or ``--duration`` stop the recording and close the file cleanly.

Sessions: with ``--connect`` only (or neither option: the node's default endpoint) the recorder
is a Zenoh client of that endpoint, so the node routes other clients' traffic (``radical replay``)
to it; it waits (retrying) until the endpoint is up. With ``--listen`` it is a peer.

Examples::

    radical record -o run.mcap --vehicle messenger                      # until Ctrl-C
    radical record -o tlm.mcap --vehicle messenger --topics tlm/small,fault --duration 600
    radical record -o all.mcap --vehicle '*' --listen tcp/127.0.0.1:7450

Exit status: 0 recorded, 1 Zenoh failure, 2 bad input (output not writable, bad option), 3
recorded but messages were dropped (queue full) or lost (end-of-stream markers).

This module is the command line; the recording is :mod:`replayer.recorder`, the Zenoh sessions
:mod:`replayer.sessions`.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import threading

from radical_rt.io import zauth
from radical_rt.io.archive import ArchiveError
from radical_rt.io.outpaths import output_file
from replayer.recorder import RecordError, check_vehicle, parse_topics, record
from replayer.sessions import ReplayError, open_session, tool_config

# -------------------------------------------------------------------------------------- CLI
#: the subcommand's line in `radical --help`
HELP = "record radical/<vehicle>/** keys to MCAP"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("-o", "--output", required=True, metavar="OUT.mcap", type=output_file, help="archive to write")
    p.add_argument("--vehicle", required=True,
                   help="vehicle name ([a-z0-9_-]+), or '*' for all vehicles (topics then "
                        "keep the vehicle: /<vehicle>/<topic>)")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S seconds (default: until SIGINT/SIGTERM)")
    p.add_argument("--topics", default=None, metavar="T1,T2",
                   help="only these topics, e.g. siru,st1,tlm/small (default: all)")
    p.add_argument("--listen", metavar="EP", help="listen on EP (tcp/127.0.0.1:PORT)")
    p.add_argument("--connect", metavar="EP", help="connect to EP (default: the node's "
                   "default endpoint tcp/127.0.0.1:7448)")
    p.add_argument("--zenoh-config", metavar="FILE",
                   help="Zenoh JSON5 file loaded first (endpoints and scouting still enforced)")
    zauth.add_auth_arguments(p, "operator")
    p.add_argument("--flush-every", type=float, default=0.5, metavar="S",
                   help="close the chunk and flush the file every S seconds (default 0.5)")
    p.add_argument("--queue", type=int, default=65536, metavar="N",
                   help="receive queue length (default 65536)")
    p.add_argument("--json", action="store_true", help="print the result as JSON on stdout")


class _Announce(threading.Event):
    """A ready event that prints one line on stderr when set (the subscribers are declared)."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self._text = text

    def set(self) -> None:
        print(self._text, file=sys.stderr, flush=True)
        super().set()


def _err(msg: str) -> None:
    print(f"radical record: error: {' '.join(str(msg).split())}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    import zenoh

    from radical_rt.io import zconfig

    try:
        check_vehicle(args.vehicle)
        parse_topics(args.topics)
        if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
            raise RecordError(f"--duration must be > 0 s, got {args.duration!r}")
        if not (math.isfinite(args.flush_every) and args.flush_every > 0) or args.queue < 1:
            raise RecordError("--flush-every must be > 0 s and --queue >= 1")
        out_dir = os.path.dirname(os.path.abspath(args.output))
        if os.path.isdir(args.output):
            raise RecordError(f"{args.output}: is a directory")
        if not os.path.isdir(out_dir):
            raise RecordError(f"{args.output}: cannot create archive: no directory {out_dir}")
        sa = zauth.from_args(args, "operator")
        if sa is not None and args.topics is None:  # a "**" subscription is not granted
            if not zauth.readable_topics(sa.role):
                raise zauth.AuthError(f"role {sa.role} may not subscribe to anything: record "
                                      "with --role operator (inputs and outputs) or monitor")
            args.topics = ",".join(zauth.readable_topics(sa.role))
        cfg, mode, where = tool_config(args.listen, args.connect, "record", args.zenoh_config,
                                       auth=sa)
    except (RecordError, zconfig.ZenohConfigError, zauth.AuthError) as e:
        _err(str(e))
        return 2
    except Exception as e:  # e.g. an unreadable --zenoh-config file
        _err(f"{type(e).__name__}: {e}")
        return 2

    stop = threading.Event()
    old = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            old[sig] = signal.signal(sig, lambda *_: stop.set())
    waiting: list[str] = []

    def on_retry(err: str) -> None:  # a client whose endpoint is not up (yet): say it once
        if not waiting:
            waiting.append(err)
            print(f"radical record: waiting for the endpoint ({where}): {err}", file=sys.stderr,
                  flush=True)

    try:
        zenoh.try_init_log_from_env()
        try:
            session = open_session(cfg, mode, math.inf, stop, on_retry)
        except ReplayError as e:
            _err(f"{e} ({where}); nothing recorded")
            return 1
        try:
            what = "**" if args.topics is None else "{" + args.topics + "}"
            ready = _Announce(f"radical record: recording radical/{args.vehicle}/{what} to "
                              f"{args.output} ({where}); SIGINT/SIGTERM to stop")
            try:
                res = record(args.output, args.vehicle, session, duration=args.duration,
                             topics=args.topics, stop_event=stop, ready_event=ready,
                             queue_size=args.queue, flush_every_s=args.flush_every)
            except (RecordError, ArchiveError) as e:
                _err(str(e))
                return 2
        finally:
            session.close()
    finally:
        for sig, h in old.items():
            signal.signal(sig, h)
    per = ", ".join(f"{t} {n}" for t, n in res["counts"].items()) or "nothing"
    print(f"radical record: wrote {res['messages']} messages ({per}) to {res['path']} in "
          f"{res['wall_s']:.1f} s; dropped {res['dropped']}; lost {res['lost']} (reported by "
          f"{res['eos']} end-of-stream marker(s))", file=sys.stderr)
    if args.json:
        print(json.dumps(res, sort_keys=True))
    return 3 if res["dropped"] or res["lost"] else 0
