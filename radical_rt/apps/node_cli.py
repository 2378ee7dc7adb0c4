"""Run the streaming calibration filter over Zenoh (one process, one or more vehicles).

    radical node --vehicle V [--vehicle V2 ...] [--listen EP] [--connect EP] [--zenoh-config FILE]
                 [--config PARAMS.toml] [--packets PACKETS.toml] [--resume CKPT]
                 [--checkpoint PATH] [--checkpoint-every S] [--duration S]

Subscribes to ``radical/<V>/{siru,st1,st2,temp}``, publishes ``radical/<V>/tlm/{small,medium,large}``,
``fault`` and ``diag``, answers commands on ``radical/<V>/cmd`` and holds the liveliness token
``radical/<V>/alive/filter``. With neither --listen nor --connect it listens on
tcp/127.0.0.1:7448. SIGINT/SIGTERM: final checkpoint, undeclare, close. See docs/node.md.
"""

from __future__ import annotations

import argparse
import gc
import logging
import signal
import sys
import threading
import time
from typing import Any

from radical_rt.io import zauth, zconfig
from radical_rt.io.outpaths import output_file

log = logging.getLogger("radical.node")
#: the thread switch interval of a node or fleet worker [ms]. Each input sample is queued by a
#: callback on Zenoh's receive thread, which must take the GIL from the busy filter loop; with
#: Python's 5 ms a sample could wait that long per hand-over. 0.5 ms: a fleet on 2 vCPUs served
#: 24 per-read vehicles at real time instead of 10 (perf/README.md, "Fleet capacity").
GIL_SWITCH_MS = 0.5


#: the subcommand's line in `radical --help`
HELP = "run the streaming filter node over Zenoh"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--vehicle", action="append", metavar="V",
                   help="vehicle name [a-z0-9_-]+ (repeat to serve several vehicles; with "
                        "--fleet: the roster)")
    p.add_argument("--fleet", metavar="NAME", help="run fleet workers of fleet NAME that share "
                   "the roster among themselves (needs --connect to a router; docs/fleet.md)")
    p.add_argument("--roster", metavar="FILE", help="with --fleet: vehicle names, one per line")
    p.add_argument("--workers", type=int, metavar="N", help="with --fleet: worker processes "
                   "(default: one per CPU core)")
    p.add_argument("--discover", nargs="?", const="siru", choices=("siru", "st1", "st2", "temp"),
                   metavar="TOPIC", help="with --fleet: add to the fleet's roster the vehicles "
                   "whose inputs appear on radical/<V>/TOPIC (default siru, the one topic every "
                   "source sends; temp is cheaper where all send it). One worker of the fleet "
                   "watches; off by default (docs/fleet.md, \"Discovery\")")
    p.add_argument("--listen", metavar="EP", help="listen on this loopback endpoint "
                   f"(tcp/127.0.0.1:PORT; default {zconfig.DEFAULT_ENDPOINT} if no --connect)")
    p.add_argument("--connect", metavar="EP", help="connect to a router/peer at this endpoint")
    p.add_argument("--mode", choices=("peer", "client", "router"), default="peer",
                   help="Zenoh session mode (default peer)")
    p.add_argument("--zenoh-config", metavar="FILE", help="Zenoh JSON5 configuration loaded first "
                   "(endpoints and multicast scouting are still forced to the loopback rules)")
    zauth.add_auth_arguments(p, "node")
    p.add_argument("--config", metavar="PARAMS.toml", help="parameter overrides ([params] table)")
    p.add_argument("--packets", metavar="PACKETS.toml", help="telemetry packet configuration")
    p.add_argument("--clock", choices=("reconstruct", "naive"), default="reconstruct",
                   help="SIRU time tags: online reconstruction (default) or naive bus tags")
    p.add_argument("--resume", metavar="CKPT",
                   help="restore the state of a checkpoint and continue its stream "
                   "(see --resume-new-stream, --force-vehicle)")
    p.add_argument("--resume-bump", action="store_true",
                   help="apply the configured covariance bump when resuming")
    p.add_argument("--force-vehicle", action="store_true",
                   help="resume even from a checkpoint of another vehicle (default: refused)")
    p.add_argument("--resume-new-stream", action="store_true",
                   help="resume the calibration but start a new stream (clock phase forgotten, "
                        "warm start); default: continue the checkpointed stream")
    p.add_argument("--checkpoint", metavar="PATH", type=output_file,
                   help="checkpoint file (written periodically, on command and at shutdown)")
    p.add_argument("--checkpoint-every", type=float, default=None, metavar="S",
                   help="seconds of wall time between checkpoints (default 60; fleet: 10)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds of wall time")
    p.add_argument("--queue-size", type=int, default=4096, metavar="N",
                   help="input FIFO capacity in samples (default 4096; full: back-pressure)")
    p.add_argument("--queue-bytes", type=int, default=64 << 20, metavar="BYTES",
                   help="input FIFO bound in payload bytes (default 64 MiB; full: wait 1 s, then "
                        "drop and count; 0: no byte bound, the pulled Zenoh FIFO)")
    p.add_argument("--stale-after", type=float, default=3.0, metavar="S",
                   help="no input for S s of wall time while a stream is active: LINK_LOSS "
                        "(default 3; 0: no link watch)")
    p.add_argument("--idle-release", type=float, default=10.0, metavar="S",
                   help="release the samples held for reordering after S s of wall time without "
                        "input (default 10; 0: only at an end-of-stream marker)")
    p.add_argument("--max-payload", type=int, default=1 << 20, metavar="BYTES",
                   help="largest input payload taken (default 1 MiB; larger: refused unread)")
    p.add_argument("--block-outputs", action="store_true",
                   help="BLOCK congestion control for all outputs (default: fault only)")
    p.add_argument("--rt-priority", type=int, metavar="N",
                   help="run the filter loop with the real-time policy SCHED_FIFO at priority "
                        "N (1-99; needs root or CAP_SYS_NICE; default: time-sharing)")
    p.add_argument("--gil-switch-ms", type=float, default=GIL_SWITCH_MS, metavar="MS",
                   help="the interpreter's thread switch interval (default %(default)g ms; "
                        "Python's own is 5): how long Zenoh's receive thread may wait for the "
                        "filter loop to hand over the GIL for each input sample")
    p.add_argument("--log-level", default="info", choices=("debug", "info", "warning", "error"))
    p.add_argument("--timing-out", metavar="PATH.npz", type=output_file,
                   help="record per-message filter-loop timing (monotonic ns: taken, loop, fed, "
                        "published) and garbage collections; write them to PATH.npz at exit "
                        "(perf/bench_latency.py)")


def _fail(msg: str) -> int:
    print(f"radical node: {msg}", file=sys.stderr)
    return 2


def _check(args: argparse.Namespace) -> str | None:
    """Argument errors that need no work (one line each)."""
    for ep in (args.listen, args.connect):
        if ep is not None:
            try:
                zconfig.check_endpoint(ep)
            except zconfig.ZenohConfigError as exc:
                return str(exc)
    if args.checkpoint_every is not None and args.checkpoint_every <= 0:
        return "--checkpoint-every must be > 0"
    if args.fleet is None:
        if not args.vehicle:
            return "give at least one --vehicle V (or --fleet NAME with a roster)"
        for opt, given in (("--roster", args.roster), ("--workers", args.workers),
                           ("--discover", args.discover)):
            if given is not None:
                return f"{opt} needs --fleet NAME"
    if args.duration is not None and args.duration <= 0:
        return "--duration must be > 0"
    if args.queue_size < 1:
        return "--queue-size must be ≥ 1"
    if not args.idle_release >= 0:
        return "--idle-release must be ≥ 0"
    if args.queue_bytes < 0:
        return "--queue-bytes must be ≥ 0 (0: no byte bound)"
    if not args.stale_after >= 0:
        return "--stale-after must be ≥ 0 (0: no link watch)"
    if 0 < args.queue_bytes < args.max_payload:
        return "--queue-bytes must be ≥ --max-payload (or 0: no byte bound)"
    if args.max_payload < 1024:
        return "--max-payload must be ≥ 1024"
    if args.rt_priority is not None and not 1 <= args.rt_priority <= 99:
        return "--rt-priority must be 1..99"
    if not 0.05 <= args.gil_switch_ms <= 100:
        return "--gil-switch-ms must be 0.05..100"
    for opt, given in (("--resume-bump", args.resume_bump),
                       ("--resume-new-stream", args.resume_new_stream),
                       ("--force-vehicle", args.force_vehicle)):
        if given and not args.resume:
            return f"{opt} needs --resume"
    return None  # (--checkpoint / --timing-out: radical_rt.io.outpaths, while parsing)


class CliLogHandler(logging.StreamHandler):
    """The stderr handler the command line installs (found again and replaced on a new setup)."""


def _setup_logging(level: str) -> None:
    """The node's log lines go to stderr ("radical node: LEVEL message"), whatever root has."""
    logger = logging.getLogger("radical")
    for h in [h for h in logger.handlers if isinstance(h, CliLogHandler)]:
        logger.removeHandler(h)
    h = CliLogHandler(sys.stderr)
    h.setFormatter(logging.Formatter("radical node: %(levelname)s %(message)s"))
    logger.addHandler(h)
    logger.setLevel(getattr(logging, level.upper()))
    logger.propagate = False


def run(args: argparse.Namespace) -> int:
    _setup_logging(args.log_level)
    err = _check(args)
    if err:
        return _fail(err)
    if args.fleet is not None:
        from radical_rt.apps.fleet_cli import run_fleet

        return run_fleet(args)
    args.checkpoint_every = args.checkpoint_every or 60.0
    from radical_rt.apps.node import FilterNode, NodeStartError
    from radical_rt.apps.node_setup import build_processors, warm_up
    from radical_rt.apps.node_timing import LoopTiming
    from radical_rt.contract.params import ParamError
    from radical_rt.io.checkpoint import CheckpointError
    from radical_rt.io.transport import TransportError
    from radical_rt.stream.telemetry import PacketError

    try:
        processors = build_processors(args.vehicle, args.config, args.packets, args.clock,
                                      args.resume, args.resume_bump, args.force_vehicle,
                                      args.resume_new_stream)
    except (ValueError, ParamError, PacketError, CheckpointError) as exc:
        return _fail(str(exc))
    log.info("compiling Numba kernels (first run only: up to a minute; later runs load them "
             "from the cache)…")
    jit_s = warm_up(args.clock)
    log.info("Numba kernels ready in %.2f s", jit_s)
    sys.setswitchinterval(args.gil_switch_ms * 1e-3)
    # Everything allocated so far (modules, compiled kernels, processors) lives for the whole run:
    # move it out of the collector's reach so that full collections only scan what the stream
    # allocates (shorter GC pauses in the filter loop).
    gc.collect()
    gc.freeze()

    try:
        transport, sa, listen, connect = _open_session(args)
    except (TransportError, zconfig.ZenohConfigError, zauth.AuthError) as exc:
        return _fail(str(exc))
    timing = None
    if args.timing_out:
        timing = LoopTiming(list(processors))
        timing.watch_gc()
    node = FilterNode(transport, processors, checkpoint_path=args.checkpoint,
                      checkpoint_every_s=args.checkpoint_every, queue_size=args.queue_size,
                      block_outputs=args.block_outputs, timing=timing,
                      rt_priority=args.rt_priority,
                      idle_release_s=args.idle_release or None,
                      max_payload_bytes=args.max_payload,
                      queue_bytes=args.queue_bytes or None,
                      stale_after_s=args.stale_after or None,
                      auth=sa.profile if sa is not None else None)
    stop = threading.Event()
    got: list[str] = []

    def on_signal(signum: int, _frame: object) -> None:
        got.append(signal.Signals(signum).name)
        stop.set()

    try:
        node.start()
    except NodeStartError as exc:
        transport.close()
        return _fail(str(exc))
    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        log.info("listening on %s, connecting to %s; ready", listen or "-", connect or "-")
        end = time.monotonic() + args.duration if args.duration else None
        while not stop.is_set():
            if end is not None and time.monotonic() >= end:
                break
            if node.loop_error is not None:
                log.error("filter loop failed: %s", node.loop_error)
                break
            stop.wait(0.2)
        log.info("stopping (%s)", got[0] if got else "duration reached" if end else "loop error")
    finally:
        try:
            node.stop()
            if args.checkpoint:
                log.info("final checkpoint written to %s", args.checkpoint)
        except Exception as exc:
            log.error("final checkpoint failed: %s", exc)
        if node.timing is not None:
            try:
                node.timing.save(args.timing_out)
            except OSError as exc:
                log.error("cannot write --timing-out %s: %s", args.timing_out, exc)
        transport.close()
        for s, h in old.items():
            signal.signal(s, h)
    return 1 if node.loop_error is not None else 0


def _open_session(args: argparse.Namespace) -> tuple[Any, zauth.SessionAuth | None, list[str],
                                                    list[str]]:
    """The node's Zenoh transport and its authentication (``--auth``/``--role``). Listening
    with a profile, the node is the enforcement point (usrpwd dictionary, access control, TLS
    server certificate); connecting only, it is a client of a router that enforces them."""
    import zenoh

    from radical_rt.io.zenoh_transport import ZenohTransport

    zenoh.try_init_log_from_env()  # Zenoh's own log (e.g. ACL denials) only if RUST_LOG is set
    sa = zauth.from_args(args, "node")
    listen, connect = zconfig.endpoints(args.listen, args.connect, "node",
                                        default=sa.profile.endpoint if sa else None)
    mode, extra = args.mode, None
    if sa is not None:
        extra = sa.profile.client_settings(sa.user)
        if listen:
            extra.update(sa.settings(listening=True))
        else:
            mode = "client"  # a router enforces the profile; a peer would gossip around it
        log.info("security profile %s: %s, user %s (role %s)", sa.profile.directory,
                 sa.profile.describe()["auth"], sa.user, sa.role)
    else:
        log.warning("UNAUTHENTICATED: no --auth profile, so any process that reaches %s can read "
                    "every key, publish inputs and send any command (docs/security.md; create a "
                    "profile with `radical keys init DIR`)", ", ".join(listen + connect))
    transport = ZenohTransport(mode, listen, connect, config_file=args.zenoh_config, extra=extra)
    return transport, sa, listen, connect
