"""Send one command to a node and print its reply (CONTRACT §3.2; docs/node.md "Commands").

    radical cmd --vehicle V NAME [--args JSON] [--timeout S] [--listen EP | --connect EP]
                [--zenoh-config FILE] [--auth DIR [--role ROLE]] [--json]

NAME is a command (``status``, ``get_params``, ``set_params``, ``cold_start``, …) and ``--args``
a JSON map of its arguments, e.g. ``--args '{"params": {"sigma_st_xy_arcsec": 4.0}}'``. Without
``--auth`` the request goes to the contract's key ``radical/<V>/cmd``; with a security profile to
the user's own key, ``radical/<V>/cmd/read/<user>`` for a ``monitor`` (the default role) or
``cmd/write/<user>`` for an ``operator`` (docs/security.md). The reply is printed as JSON.
Exit status: 0 for a reply with ``ok: true``; 1 for ``ok: false``, no reply (no node serves V, or
the access control refused the query) or a session that cannot open; 2 for a bad option.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from radical_rt.io import zauth, zconfig

#: the subcommand's line in `radical --help`
HELP = "send one command to a node and print the reply"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--vehicle", required=True, metavar="V", help="vehicle name [a-z0-9_-]+")
    p.add_argument("name", metavar="NAME", help="command name, e.g. status, set_params, cold_start")
    p.add_argument("--args", metavar="JSON", default=None,
                   help='the command\'s arguments as a JSON map, e.g. \'{"gyro": 2}\'')
    p.add_argument("--id", metavar="ID", default=None, help="request id echoed in the reply")
    p.add_argument("--timeout", type=float, default=5.0, metavar="S",
                   help="seconds to wait for the reply (default 5)")
    p.add_argument("--listen", metavar="EP", help="listen on a loopback endpoint")
    p.add_argument("--connect", metavar="EP", help="connect to the node or a router "
                   f"(default {zconfig.DEFAULT_ENDPOINT}, or the profile's endpoint)")
    p.add_argument("--zenoh-config", metavar="FILE", help="Zenoh JSON5 file loaded first "
                   "(loopback endpoints and multicast off are still enforced)")
    zauth.add_auth_arguments(p, "monitor")
    p.add_argument("--json", action="store_true", help="print the reply on one line")


def build_request(name: str, args_json: str | None, rid: str | None) -> dict[str, Any]:
    """The request map; ValueError with a clear message for bad --args."""
    req: dict[str, Any] = {"v": 1, "cmd": name}
    if args_json is not None:
        try:
            extra = json.loads(args_json)
        except json.JSONDecodeError as exc:
            raise ValueError(f"--args is not valid JSON: {exc}") from None
        if not isinstance(extra, dict):
            raise ValueError(f"--args must be a JSON map, got {type(extra).__name__}")
        clash = sorted({"cmd", "v"} & set(extra))
        if clash:
            raise ValueError(f"--args must not set {clash} (NAME is the command)")
        req.update(extra)
    if rid is not None:
        req["id"] = rid
    return req


def command_key(vehicle: str, sa: zauth.SessionAuth | None) -> str:
    """Where the request goes: the contract key, or the user's read/write key."""
    if sa is None:
        return f"radical/{vehicle}/cmd"
    access = "write" if sa.role in zauth.WRITE_ROLES else "read"
    return zauth.cmd_key(vehicle, access, sa.user)


def _err(msg: str) -> None:
    print(f"radical cmd: error: {msg}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    import msgpack

    from radical_rt.apps.node_vehicle import VEHICLE_RE
    from radical_rt.io.transport import TransportError
    from radical_rt.io.zenoh_transport import ZenohTransport

    try:
        if not VEHICLE_RE.match(args.vehicle):
            raise ValueError(f"vehicle name {args.vehicle!r} must match [a-z0-9_-]+")
        if not args.timeout > 0:
            raise ValueError(f"--timeout must be > 0 s, got {args.timeout}")
        req = build_request(args.name, args.args, args.id)
        sa = zauth.from_args(args, "monitor")
        listen, connect = zconfig.endpoints(args.listen, args.connect, "cmd",
                                            default=sa.profile.endpoint if sa else None)
    except (ValueError, zauth.AuthError, zconfig.ZenohConfigError) as exc:
        _err(str(exc))
        return 2
    key = command_key(args.vehicle, sa)
    extra = sa.settings(listening=False) if sa is not None else None
    try:
        t = ZenohTransport("peer" if listen else "client", listen, connect,
                           config_file=args.zenoh_config, extra=extra)
    except (TransportError, zconfig.ZenohConfigError) as exc:
        _err(str(exc))
        return 1
    try:
        replies = t.get(key, msgpack.packb(req, use_bin_type=True), timeout=args.timeout)
    except TransportError as exc:
        _err(str(exc))
        return 1
    finally:
        t.close()
    if not replies:
        who = f" (user {sa.user}, role {sa.role})" if sa else ""
        _err(f"no reply on {key} within {args.timeout:g} s: no node serves vehicle "
             f"{args.vehicle!r} there, or the access control refused the query{who}")
        return 1
    reply = msgpack.unpackb(replies[0], raw=False, strict_map_key=False)
    print(json.dumps(reply, default=str) if args.json else json.dumps(reply, indent=2, default=str))
    return 0 if isinstance(reply, dict) and reply.get("ok") is True else 1
