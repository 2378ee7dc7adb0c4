"""Security profiles: who may reach which key of the live system (docs/security.md).

A profile is a directory written by ``radical keys init DIR`` (:mod:`radical_rt.apps.keys_cli`):

* ``profile.json``: endpoint, TLS on/off, users and their roles (:data:`ROLES`);
* ``users.txt``: ``user:password`` lines, the enforcement point's usrpwd dictionary (mode 0600);
* with TLS: ``ca.pem``/``ca.key``, ``server.pem``/``.key`` and ``<user>.pem``/``.key`` (CN = user);
* ``<role>.json5``: a ready Zenoh client configuration per role (any Zenoh client can load it),
  ``router.json5``: the enforcement point's configuration (zenohd, or a listening node).

Everything is enforced by Zenoh itself at the enforcement point (the listening node, or a zenohd
router with ``router.json5``): usrpwd authentication refuses a session without valid credentials,
TLS (mutual: clients present a certificate of the profile's CA) refuses a wrong certificate, and
the access-control list (default deny) allows each user exactly what its role needs:

===========  ===========================================================================
role         may
===========  ===========================================================================
sensor       put inputs ``radical/*/{siru,st1,st2,temp,eos}``; see liveliness tokens
node         everything under ``radical/**`` and ``radical-fleet/**`` (subscribe inputs, publish
             outputs, serve commands; a fleet's membership, ownership and checkpoints)
monitor      subscribe outputs ``radical/*/{tlm/**,fault,diag,cmd_log}``; read-only commands on
             ``radical/*/cmd/read/<user>``; see liveliness tokens; ``radical fleet status``
             and the fleet's roster
operator     what a monitor may, plus subscribe inputs and every command on
             ``radical/*/cmd/write/<user>``; ``radical fleet add/remove``
===========  ===========================================================================

The user's own name is the last chunk of its command keys, so the node knows who sent a command
from the key alone (the ACL has checked it). The contract's ``radical/<V>/cmd`` is granted to
nobody but the node in a profile.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

ROLES = ("sensor", "node", "monitor", "operator")
#: the role that may send state-changing commands (on the write key)
WRITE_ROLES = ("operator",)
#: roles that may send read-only commands (on the read key)
READ_ROLES = ("monitor", "operator")
INPUT_TOPICS = ("siru", "st1", "st2", "temp", "eos")
OUTPUT_TOPICS = ("tlm/**", "fault", "diag", "cmd_log")
SCHEMA = "radical.auth/1"
ALL_MESSAGES = ("put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                "liveliness_token", "liveliness_query", "declare_liveliness_subscriber")


class AuthError(ValueError):
    """A missing or malformed profile, or a role it does not have (message says which)."""


def cmd_key(vehicle: str, access: str, user: str) -> str:
    """The command key of ``user``: ``radical/<vehicle>/cmd/<access>/<user>`` (access: read|write)."""
    if access not in ("read", "write"):
        raise ValueError(f"access must be read or write, got {access!r}")
    return f"radical/{vehicle}/cmd/{access}/{user}"


@dataclass
class Profile:
    """A loaded security profile. ``users``: user → role; ``passwords``: user → password."""

    directory: Path
    endpoint: str
    tls: bool
    users: dict[str, str]
    passwords: dict[str, str] = field(repr=False, default_factory=dict)

    # ---------------------------------------------------------------- loading
    @classmethod
    def load(cls, directory: str | os.PathLike) -> Profile:
        """Read ``DIR/profile.json`` and ``DIR/users.txt``; AuthError with the reason if unusable."""
        d = Path(directory)
        meta = d / "profile.json"
        try:
            info = json.loads(meta.read_text())
        except FileNotFoundError:
            raise AuthError(f"{d} is not a security profile (no profile.json); "
                            f"create one with: radical keys init {d}") from None
        except (OSError, ValueError) as exc:
            raise AuthError(f"cannot read {meta}: {exc}") from None
        if not isinstance(info, dict) or info.get("schema") != SCHEMA:
            raise AuthError(f"{meta}: not a {SCHEMA} profile")
        users = info.get("users")
        if not isinstance(users, dict) or any(r not in ROLES for r in users.values()):
            raise AuthError(f"{meta}: 'users' must map user names to roles {ROLES}")
        prof = cls(d.resolve(), str(info.get("endpoint")), bool(info.get("tls")), dict(users))
        if (d / "users.txt").exists():  # the whole profile (the enforcement point's copy)
            prof.passwords = _read_dictionary(d / "users.txt")
            missing = sorted(set(users) - set(prof.passwords))
            if missing:
                raise AuthError(f"{d / 'users.txt'}: no password for {missing}")
        else:  # a user's kit: profile.json, ca.pem and that user's own files only
            prof.passwords = _kit_passwords(d, users)
            if not prof.passwords:
                raise AuthError(f"{d} holds no credentials (neither users.txt nor a "
                                "<role>.json5 client configuration)")
        return prof

    def user_of(self, role: str) -> str:
        """The profile's user for ``role`` whose credentials this copy holds (the first listed);
        AuthError if there is none."""
        if role not in ROLES:
            raise AuthError(f"unknown role {role!r}; roles: {', '.join(ROLES)}")
        for user, r in self.users.items():
            if r == role and user in self.passwords:
                return user
        raise AuthError(f"profile {self.directory} holds no credentials of a user with role "
                        f"{role!r}")

    def role_of(self, user: str) -> str | None:
        """The role of ``user``, None if the profile does not know it."""
        return self.users.get(user)

    def describe(self) -> dict[str, Any]:
        """What diag and status say about the node's security (no secret)."""
        return {"auth": "usrpwd+mtls" if self.tls else "usrpwd", "profile": str(self.directory),
                "endpoint": self.endpoint, "users": len(self.users)}

    # ---------------------------------------------------------------- Zenoh settings
    def client_settings(self, user: str) -> dict[str, Any]:
        """Config key path → value for a session of ``user`` that connects to the enforcement
        point (credentials; with TLS the CA and the user's certificate)."""
        if user not in self.passwords:
            raise AuthError(f"profile {self.directory} holds no credentials of user {user!r}")
        out: dict[str, Any] = {"transport/auth/usrpwd/user": user,
                               "transport/auth/usrpwd/password": self.passwords[user]}
        if self.tls:
            out.update({"transport/link/tls/root_ca_certificate": str(self.directory / "ca.pem"),
                        "transport/link/tls/enable_mtls": True,
                        "transport/link/tls/connect_certificate": str(self.directory / f"{user}.pem"),
                        "transport/link/tls/connect_private_key": str(self.directory / f"{user}.key")})
        return out

    def listener_settings(self) -> dict[str, Any]:
        """Config key path → value for the enforcement point (the node that listens, or a
        router): the usrpwd dictionary, the access-control list, with TLS the server certificate
        and client-certificate checking."""
        if not (self.directory / "users.txt").exists():
            raise AuthError(f"{self.directory} is a user's kit (no users.txt): only the whole "
                            "profile can run the enforcement point")
        out: dict[str, Any] = {
            "transport/auth/usrpwd/dictionary_file": str(self.directory / "users.txt"),
            "access_control": access_control(self.users, self.tls)}
        if self.tls:
            out.update({"transport/link/tls/listen_certificate": str(self.directory / "server.pem"),
                        "transport/link/tls/listen_private_key": str(self.directory / "server.key"),
                        "transport/link/tls/root_ca_certificate": str(self.directory / "ca.pem"),
                        "transport/link/tls/enable_mtls": True})
        return out


def _kit_passwords(d: Path, users: dict[str, str]) -> dict[str, str]:
    """user → password from the client configurations in a user's kit (``<role>.json5``,
    ``user-<name>.json5``)."""
    out = {}
    for f in sorted(d.glob("*.json5")):
        if f.name == "router.json5":
            continue
        try:
            doc = json.loads(f.read_text().split("\n", 1)[1])
            cred = doc["transport"]["auth"]["usrpwd"]
        except (OSError, ValueError, KeyError, IndexError, TypeError):
            continue  # not one of ours
        if cred.get("user") in users and isinstance(cred.get("password"), str):
            out[cred["user"]] = cred["password"]
    return out


def _read_dictionary(path: Path) -> dict[str, str]:
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise AuthError(f"cannot read {path}: {exc.strerror or exc}") from None
    out = {}
    for line in lines:
        if line.strip():
            user, sep, pw = line.partition(":")
            if not sep:
                raise AuthError(f"{path}: lines must be user:password")
            out[user] = pw
    return out


# -------------------------------------------------------------------------------- access control
def _rule(rid: str, messages: tuple[str, ...] | list[str], flows: list[str],
          keys: list[str]) -> dict[str, Any]:
    return {"id": rid, "messages": list(messages), "flows": flows, "permission": "allow",
            "key_exprs": keys}


def access_control(users: dict[str, str], tls: bool = False) -> dict[str, Any]:
    """The Zenoh ``access_control`` section (default deny) for ``users`` (user → role)."""
    inputs = [f"radical/*/{t}" for t in INPUT_TOPICS]
    outputs = [f"radical/*/{t}" for t in OUTPUT_TOPICS]
    alive = ["radical/*/alive/**"]
    rules = [
        _rule("node_all", ALL_MESSAGES, ["ingress", "egress"], ["radical/**", "radical-fleet/**"]),
        _rule("fleet_status", ["query"], ["ingress"], ["radical-fleet/*/status/*"]),
        _rule("fleet_status_out", ["reply", "declare_queryable"], ["egress"],
              ["radical-fleet/*/status/*"]),
        # the fleet's roster (docs/fleet.md "Roster"): read the workers' rosters and see which
        # workers are alive (monitor, operator); publish edits (operator: radical fleet add)
        _rule("fleet_roster", ["query"], ["ingress"], ["radical-fleet/*/roster-state/*"]),
        _rule("fleet_roster_out", ["reply", "declare_queryable"], ["egress"],
              ["radical-fleet/*/roster-state/*"]),
        _rule("fleet_workers", ["liveliness_query", "declare_liveliness_subscriber"], ["ingress"],
              ["radical-fleet/*/worker/*"]),
        _rule("fleet_workers_out", ["liveliness_token", "reply"], ["egress"],
              ["radical-fleet/*/worker/*"]),
        _rule("fleet_roster_edit", ["put"], ["ingress"], ["radical-fleet/*/roster/*"]),
        _rule("fleet_roster_routes", ["declare_subscriber"], ["egress"],
              ["radical-fleet/*/roster/*"]),
        _rule("inputs_put", ["put"], ["ingress"], inputs),
        # routes: a client only sends a put when it knows a matching subscriber, and the node
        # subscribes with wildcards (radical/<V>/*, radical/*/*): the declarations (key
        # expressions, never data) are shown to every client
        _rule("routes", ["declare_subscriber"], ["egress"], ["radical/**"]),
        _rule("inputs_read", ["declare_subscriber"], ["ingress"], inputs),
        _rule("inputs_read_out", ["put"], ["egress"], inputs),
        _rule("outputs_read", ["declare_subscriber"], ["ingress"], outputs),
        _rule("outputs_read_out", ["put"], ["egress"], outputs),
        _rule("alive_read", ["liveliness_query", "declare_liveliness_subscriber"], ["ingress"], alive),
        _rule("alive_read_out", ["liveliness_token", "reply"], ["egress"], alive),
        _rule("cmd_routes", ["declare_queryable"], ["egress"], ["radical/*/cmd/**"]),
    ]
    role_rules = {"node": ["node_all"], "sensor": ["inputs_put", "routes", "alive_read",
                                                   "alive_read_out"],
                  "monitor": ["outputs_read", "outputs_read_out", "alive_read", "alive_read_out",
                              "routes", "fleet_status", "fleet_status_out", "fleet_roster",
                              "fleet_roster_out", "fleet_workers", "fleet_workers_out"],
                  "operator": ["outputs_read", "outputs_read_out", "alive_read", "alive_read_out",
                               "inputs_read", "inputs_read_out", "routes", "fleet_status",
                               "fleet_status_out", "fleet_roster", "fleet_roster_out",
                               "fleet_workers", "fleet_workers_out", "fleet_roster_edit",
                               "fleet_roster_routes"]}
    subjects, policies = [], []
    for i, (user, role) in enumerate(sorted(users.items())):
        sid = f"u{i}_{user}"
        subject: dict[str, Any] = {"id": sid, "usernames": [user]}
        if tls:
            subject["cert_common_names"] = [user]
        subjects.append(subject)
        mine = list(role_rules[role])
        keys = ([cmd_key("*", "read", user)] if role in READ_ROLES else []) + \
               ([cmd_key("*", "write", user)] if role in WRITE_ROLES else [])
        if keys:
            rules.append(_rule(f"cmd_in_{sid}", ["query"], ["ingress"], keys))
            rules.append(_rule(f"cmd_out_{sid}", ["reply"], ["egress"], keys))
            mine += [f"cmd_in_{sid}", f"cmd_out_{sid}", "cmd_routes"]
        policies.append({"id": f"p_{sid}", "rules": mine, "subjects": [sid]})
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}


def readable_topics(role: str) -> list[str]:
    """The topics of a vehicle a role may subscribe to (a recorder's default under a profile)."""
    outputs = ["tlm/*", "fault", "diag", "cmd_log"]
    if role == "operator":
        return [*INPUT_TOPICS, *outputs]
    return outputs if role == "monitor" else []


# -------------------------------------------------------------------------------- command line
def add_auth_arguments(p: Any, default_role: str) -> None:
    """``--auth DIR --role ROLE`` on a command that opens a Zenoh session."""
    p.add_argument("--auth", metavar="DIR", help="security profile written by `radical keys init "
                   "DIR`: authenticate (and with TLS encrypt) the session (docs/security.md)")
    p.add_argument("--role", choices=ROLES, default=None,
                   help=f"role of this session in the profile (default {default_role}; "
                        "needs --auth)")
    p.add_argument("--user", metavar="NAME", default=None,
                   help="user of the profile to act as (default: the role's own user; needs "
                        "--auth; its role is the profile's)")


@dataclass
class SessionAuth:
    """What a tool's session needs from ``--auth DIR --role ROLE``: the profile and the user."""

    profile: Profile
    role: str
    user: str

    def settings(self, listening: bool) -> dict[str, Any]:
        """Config entries: the enforcement point's (a listening node) or a client's."""
        if listening:
            if self.role != "node":
                raise AuthError(f"only the node listens as the enforcement point (role {self.role} "
                                "must --connect to it or to a router)")
            return self.profile.listener_settings()
        return self.profile.client_settings(self.user)


def session_auth(auth_dir: str | None, role: str | None, default_role: str,
                 user: str | None = None) -> SessionAuth | None:
    """The session's authentication from ``--auth``/``--role``/``--user`` (None without --auth);
    AuthError for --role/--user without --auth, a bad profile, an unknown user, a user whose
    role is not --role, or a role the profile has no user for."""
    if auth_dir is None:
        if role is not None or user is not None:
            raise AuthError("--role/--user need --auth DIR (a profile from `radical keys init DIR`)")
        return None
    prof = Profile.load(auth_dir)
    if user is not None:
        urole = prof.role_of(user)
        if urole is None:
            raise AuthError(f"profile {prof.directory} has no user {user!r}")
        if role is not None and role != urole:
            raise AuthError(f"user {user!r} has role {urole!r}, not {role!r}")
        return SessionAuth(prof, urole, user)
    r = role or default_role
    return SessionAuth(prof, r, prof.user_of(r))


def from_args(args: Any, default_role: str) -> SessionAuth | None:
    """:func:`session_auth` of a parsed command line with :func:`add_auth_arguments`."""
    return session_auth(getattr(args, "auth", None), getattr(args, "role", None), default_role,
                        getattr(args, "user", None))
