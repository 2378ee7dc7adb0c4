"""Create a security profile for the live system (docs/security.md).

    radical keys init DIR [--no-tls] [--port P] [--user ROLE:NAME ...] [--force]
    radical keys kit DIR --user NAME -o OUT

Writes a ready profile into DIR: one user per role (``sensor``, ``node``, ``monitor``,
``operator``, each named after its role, plus every ``--user``) with random passwords in
``users.txt``; unless ``--no-tls``, a loopback certificate authority, the enforcement point's server
certificate (127.0.0.1, localhost) and one client certificate per user (common name = user); the
Zenoh configurations ``DIR/<role>.json5`` (one client per role, usable by any Zenoh client) and
``DIR/router.json5`` (the enforcement point: a zenohd router, or a node that listens); and
``profile.json``. Then every command that opens a session takes ``--auth DIR --role ROLE``.
Secrets are written with mode 0600 and DIR with 0700. ``keys kit`` copies what one user needs
(profile.json, the CA certificate, the user's client configuration and certificate: no other
user's secret, no users.txt) into OUT, for ``--auth OUT``. Exit 0, 2 on a bad option or an
existing profile (``--force`` replaces it).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import secrets
import sys
from pathlib import Path

from radical_rt.io import zconfig
from radical_rt.io.zauth import ROLES, SCHEMA, AuthError, Profile

#: the subcommand's line in `radical --help`
HELP = "create a security profile (credentials, certificates, Zenoh configs per role)"
_USER = re.compile(r"^[a-z][a-z0-9_-]{0,31}$")


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="keys", metavar="{init,kit}")
    init = sub.add_parser("init", help="write a new profile into DIR")
    init.add_argument("dir", metavar="DIR", help="profile directory (created)")
    init.add_argument("--no-tls", dest="tls", action="store_false",
                      help="plain TCP links (endpoint tcp/127.0.0.1:PORT): passwords only, no "
                           "encryption (default: TLS with client certificates, tls/127.0.0.1:PORT)")
    init.add_argument("--port", type=int, default=zconfig.DEFAULT_PORT,
                      help=f"port of the enforcement point on 127.0.0.1 (default {zconfig.DEFAULT_PORT})")
    init.add_argument("--user", action="append", default=[], metavar="ROLE:NAME",
                      help="one more user with a role (repeatable), e.g. operator:alice")
    init.add_argument("--force", action="store_true", help="replace an existing profile in DIR")
    kit = sub.add_parser("kit", help="copy one user's credentials out of a profile (what to "
                         "hand to that user: no other user's secret)")
    kit.add_argument("dir", metavar="DIR", help="the whole profile (from keys init)")
    kit.add_argument("--user", required=True, metavar="NAME", help="the user the kit is for")
    kit.add_argument("-o", "--out", required=True, metavar="OUT", help="kit directory (created)")


def parse_users(specs: list[str]) -> dict[str, str]:
    """user → role: one user per role named after it, plus ``ROLE:NAME`` specs (ValueError)."""
    users = {r: r for r in ROLES}
    for spec in specs:
        role, sep, name = spec.partition(":")
        if not sep or role not in ROLES:
            raise ValueError(f"--user {spec!r}: expected ROLE:NAME with ROLE one of {', '.join(ROLES)}")
        if not _USER.match(name):
            raise ValueError(f"--user {spec!r}: a name is [a-z][a-z0-9_-]*, at most 32 characters")
        if name in users and users[name] != role:
            raise ValueError(f"--user {spec!r}: {name!r} already has role {users[name]!r}")
        users[name] = role
    return users


def init_profile(directory: str | os.PathLike, tls: bool = True, port: int = zconfig.DEFAULT_PORT,
                 users: dict[str, str] | None = None, force: bool = False) -> Profile:
    """Write a profile (see the module docstring) and return it loaded. ValueError if DIR holds
    a profile already (and not ``force``) or an argument is invalid."""
    d = Path(directory)
    users = users or parse_users([])
    endpoint = zconfig.check_endpoint(f"{'tls' if tls else 'tcp'}/127.0.0.1:{port}")
    if (d / "profile.json").exists() and not force:
        raise ValueError(f"{d} already holds a profile (use --force to replace it)")
    d.mkdir(parents=True, exist_ok=True)
    os.chmod(d, 0o700)
    _write_secret(d / "users.txt", "".join(f"{u}:{secrets.token_urlsafe(24)}\n" for u in users))
    if tls:
        from radical_rt.io import certs

        ca = certs.make_ca(d)
        certs.issue(ca, d, "server", "radical-enforcement-point", server=True)
        for user in users:
            certs.issue(ca, d, user, user, server=False)
    (d / "profile.json").write_text(json.dumps(
        {"schema": SCHEMA, "endpoint": endpoint, "tls": tls, "users": users}, indent=2) + "\n")
    prof = Profile.load(d)
    for role in ROLES:
        user = prof.user_of(role)
        _write_secret(d / f"{role}.json5", _json5(_nest({
            "mode": "client", "connect/endpoints": [endpoint], "listen/endpoints": [],
            "scouting/multicast/enabled": False, **prof.client_settings(user)})))
    for user, role in users.items():
        if user != role:  # the extra users' own client configurations
            _write_secret(d / f"user-{user}.json5", _json5(_nest({
                "mode": "client", "connect/endpoints": [endpoint], "listen/endpoints": [],
                "scouting/multicast/enabled": False, **prof.client_settings(user)})))
    (d / "router.json5").write_text(_json5(_nest({
        "mode": "router", "listen/endpoints": [endpoint], "connect/endpoints": [],
        "scouting/multicast/enabled": False, "scouting/gossip/enabled": False,
        **prof.listener_settings()})))
    return prof


def make_kit(directory: str | os.PathLike, user: str, out: str | os.PathLike) -> Path:
    """Copy ``user``'s files out of a profile: profile.json, ca.pem, the user's client
    configuration (and certificate); ValueError for an unknown user or an existing OUT."""
    prof = Profile.load(directory)
    role = prof.role_of(user)
    if role is None:
        raise ValueError(f"profile {prof.directory} has no user {user!r}")
    dst = Path(out)
    if dst.exists() and any(dst.iterdir()):
        raise ValueError(f"{dst} exists and is not empty")
    dst.mkdir(parents=True, exist_ok=True)
    os.chmod(dst, 0o700)
    src = prof.directory
    conf = f"{role}.json5" if prof.user_of(role) == user else f"user-{user}.json5"
    names = ["profile.json", conf] + (["ca.pem", f"{user}.pem", f"{user}.key"] if prof.tls else [])
    for name in names:
        data = (src / name).read_text()
        if name == conf and prof.tls:  # the kit's own certificate paths
            data = data.replace(str(src), str(dst.resolve()))
        if name.endswith((".key", ".json5")):
            _write_secret(dst / name, data)
        else:
            (dst / name).write_text(data)
    return dst


def _write_secret(path: Path, text: str) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    os.chmod(path, 0o600)


def _nest(flat: dict) -> dict:
    """{"a/b": v} → {"a": {"b": v}} (Zenoh's config key paths as a nested JSON5 document)."""
    out: dict = {}
    for path, value in flat.items():
        node = out
        *parents, last = path.split("/")
        for p in parents:
            node = node.setdefault(p, {})
        node[last] = value
    return out


def _json5(doc: dict) -> str:
    return ("// written by `radical keys init` (RADICAL-RT); JSON is valid JSON5\n"
            + json.dumps(doc, indent=2) + "\n")


def run(args: argparse.Namespace) -> int:
    if args.keys == "kit":
        try:
            out = make_kit(args.dir, args.user, args.out)
        except (ValueError, AuthError, OSError) as exc:
            print(f"radical keys: error: {exc}", file=sys.stderr)
            return 2
        print(f"kit for {args.user} written to {out}: use --auth {out} --user {args.user}")
        return 0
    if args.keys != "init":
        print("radical keys: give a subcommand: init DIR | kit DIR --user NAME -o OUT",
              file=sys.stderr)
        return 2
    try:
        prof = init_profile(args.dir, args.tls, args.port, parse_users(args.user), args.force)
    except (ValueError, AuthError, zconfig.ZenohConfigError, OSError) as exc:
        print(f"radical keys: error: {exc}", file=sys.stderr)
        return 2
    print(f"profile written to {prof.directory}: endpoint {prof.endpoint}, "
          f"{'TLS with client certificates, ' if prof.tls else ''}users "
          + ", ".join(f"{u} ({r})" for u, r in prof.users.items()))
    print(f"  start the node:   radical node --vehicle V --auth {args.dir} --role node")
    print(f"  send a command:   radical cmd --vehicle V status --auth {args.dir} --role monitor")
    print(f"  a zenohd router:  zenohd -c {prof.directory / 'router.json5'}")
    return 0
