"""Run a Zenoh router for nodes, tools and fleets (loopback only, multicast scouting off).

    radical router [--listen EP ...] [--connect EP ...] [--zenoh-config FILE]
                   [--auth DIR] [--duration S]

A router session of the eclipse-zenoh library in this process: it routes between its clients
(nodes started with ``--connect``, replayers, recorders, monitors) and to other routers given by
``--connect`` (a chain or mesh of routers). With neither option it listens on
``tcp/127.0.0.1:7447`` (Zenoh's usual router port). With ``--auth DIR`` it is the enforcement
point of a security profile (docs/security.md): it listens on the profile's endpoint with the
profile's user dictionary, access-control list and TLS certificates, exactly what
``DIR/router.json5`` gives a zenohd. Gossip is off, so peers cannot open links around it.
SIGINT/SIGTERM (or the end of ``--duration``) closes it; exit 0, 1 if the session cannot open,
2 on a bad option.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

from radical_rt.io import zauth, zconfig

#: the subcommand's line in `radical --help`
HELP = "run a Zenoh router (loopback; optionally the enforcement point of a security profile)"
#: where a router listens with neither --listen nor --connect
ROUTER_ENDPOINT = "tcp/127.0.0.1:7447"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--listen", action="append", default=[], metavar="EP",
                   help=f"listen on this loopback endpoint (repeatable; default {ROUTER_ENDPOINT}, "
                        "or the profile's endpoint with --auth)")
    p.add_argument("--connect", action="append", default=[], metavar="EP",
                   help="connect to another router (repeatable)")
    p.add_argument("--zenoh-config", metavar="FILE", help="Zenoh JSON5 file loaded first "
                   "(loopback endpoints, router mode and multicast off are still enforced)")
    p.add_argument("--auth", metavar="DIR", help="security profile (`radical keys init DIR`): "
                   "this router enforces it")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")


def router_endpoints(listen: list[str], connect: list[str],
                     profile: zauth.Profile | None) -> tuple[list[str], list[str]]:
    """(listen, connect) of the router: as given, else the default (the profile's endpoint)."""
    for ep in [*listen, *connect]:
        zconfig.check_endpoint(ep)
    if not listen and not connect:
        listen = [profile.endpoint if profile is not None else ROUTER_ENDPOINT]
    return list(listen), list(connect)


def open_router(listen: list[str], connect: list[str], profile: zauth.Profile | None = None,
                config_file: str | None = None):
    """An open zenoh.Session in router mode (gossip off; the profile's security if given)."""
    import zenoh

    extra = {"scouting/gossip/enabled": False}
    if profile is not None:
        extra.update(profile.listener_settings())
        extra.update(profile.client_settings(profile.user_of("node")))  # for --connect links
    cfg = zconfig.make_config("router", listen=listen, connect=connect, extra=extra,
                              config_file=config_file)
    return zenoh.open(cfg)


def run(args: argparse.Namespace) -> int:
    import zenoh

    try:
        profile = zauth.Profile.load(args.auth) if args.auth else None
        listen, connect = router_endpoints(args.listen, args.connect, profile)
        if args.duration is not None and not args.duration > 0:
            raise ValueError(f"--duration must be > 0 s, got {args.duration}")
    except (zauth.AuthError, zconfig.ZenohConfigError, ValueError) as exc:
        print(f"radical router: error: {exc}", file=sys.stderr)
        return 2
    zenoh.try_init_log_from_env()
    try:
        session = open_router(listen, connect, profile, args.zenoh_config)
    except Exception as exc:  # zenoh.ZError: a port in use, an unreadable file
        print(f"radical router: error: cannot open the router session: "
              f"{' '.join(str(exc).split(' at /')[0].split())}", file=sys.stderr)
        return 1
    stop = threading.Event()
    old = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    security = profile.describe()["auth"] if profile is not None else "none (unauthenticated)"
    print(f"radical router: listening on {listen or '-'}, connecting to {connect or '-'}, "
          f"security {security}; ready", file=sys.stderr, flush=True)
    try:
        end = time.monotonic() + args.duration if args.duration else None
        while not stop.wait(0.2):
            if end is not None and time.monotonic() >= end:
                break
    finally:
        session.close()
        for s, h in old.items():
            signal.signal(s, h)
    return 0
