"""Who may send which command, and the audit trail of every command (docs/security.md).

Command keys of a vehicle (CONTRACT §3.2 and its extension, docs/contract_extensions.md):

* ``radical/<V>/cmd``: the contract's key, every command, sender unknown;
* ``radical/<V>/cmd/read/<user>``: read-only commands (:data:`READ_ONLY`) only;
* ``radical/<V>/cmd/write/<user>``: every command.

With a security profile (``radical node --auth DIR``) Zenoh's access control lets each user
query only its own keys (the last chunk is its user name, so the key says who sent a command),
``monitor`` users the read key, ``operator`` users both; the gate checks the same again (a
misconfigured router must not open the write path) and refuses the contract key, whose sender is
unknown. Without a profile every key is open, as before, and the user named in a key is recorded
as claimed, not authenticated.

Every command that reaches the node, applied or refused, is audited (:class:`AuditLog`): one
record published on ``radical/<V>/cmd_log`` (msgpack, recorded by ``radical record`` as the
``/cmd_log`` channel), logged, counted and kept in the ``commands`` map of diag and status.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import msgpack

from radical_rt.apps import commands
from radical_rt.io.zauth import READ_ROLES, WRITE_ROLES, Profile

log = logging.getLogger("radical.audit")

#: commands that change nothing (the only ones a read key takes)
READ_ONLY = frozenset({"status", "get_params"})
#: the largest argument map kept in an audit record (packed bytes; larger: only its keys)
ARGS_MAX_BYTES = 2048
#: audit records kept for diag/status
KEEP_LAST = 5


def command_access(prefix: str, key: str) -> tuple[str, str | None]:
    """``(access, user)`` of a query key of the vehicle with ``prefix`` (``radical/<V>/``):
    ``("contract", None)`` for ``cmd``, ``("read"|"write", user)`` for ``cmd/<access>/<user>``,
    ``("invalid", None)`` otherwise."""
    rest = key[len(prefix):] if key.startswith(prefix) else ""
    if rest == "cmd":
        return "contract", None
    parts = rest.split("/")
    if len(parts) == 3 and parts[0] == "cmd" and parts[1] in ("read", "write") and parts[2]:
        return parts[1], parts[2]
    return "invalid", None


def authorize(access: str, user: str | None, name: str, profile: Profile | None) -> str | None:
    """None if ``user`` may send command ``name`` on a key of class ``access``; else the
    refusal's message."""
    if access == "invalid":
        return "not a command key: use radical/<V>/cmd/read/<user> or radical/<V>/cmd/write/<user>"
    if access == "read" and name not in READ_ONLY and name in commands.COMMANDS:
        return (f"{name} changes state: the read key takes only {', '.join(sorted(READ_ONLY))}; "
                f"an operator sends it on radical/<V>/cmd/write/<user>")
    if profile is None:
        return None
    if access == "contract":
        return ("this node requires authenticated commands: send them on "
                "radical/<V>/cmd/read/<user> or cmd/write/<user> (radical cmd --auth DIR --role ROLE)")
    role = profile.role_of(user or "")
    allowed = READ_ROLES if access == "read" else WRITE_ROLES
    if role not in allowed:
        return (f"user {user!r} (role {role or 'unknown'}) may not send commands on the {access} "
                f"key (roles allowed: {', '.join(allowed)})")
    return None


class AuditLog:
    """The audit trail of one node: per vehicle counts and last records; each record published
    by ``publish(vehicle_prefix + "cmd_log", packed)``. Thread-safe (query callbacks)."""

    def __init__(self, profile: Profile | None, publish: Callable[[str, bytes], None]) -> None:
        self.profile, self._publish = profile, publish
        self._lock = threading.Lock()
        self._applied: dict[str, int] = {}
        self._refused: dict[str, int] = {}
        self._last: dict[str, deque] = {}

    def who(self, access: str, user: str | None) -> dict[str, Any]:
        """The sender as recorded: user, role (from the profile), authenticated or claimed."""
        if self.profile is None:
            return {"user": user or "anonymous", "role": None, "authenticated": False}
        return {"user": user or "anonymous", "role": self.profile.role_of(user or ""),
                "authenticated": user is not None and access in ("read", "write")}

    def record(self, vehicle: str, prefix: str, access: str, user: str | None,
               request: dict[str, Any] | None, reply: dict[str, Any]) -> dict[str, Any]:
        """Audit one command (applied if ``reply["ok"]``); the record."""
        ok = bool(reply.get("ok"))
        req = request if isinstance(request, dict) else {}
        rec: dict[str, Any] = {
            "v": 1, "t_wall": time.time(), "vehicle": vehicle, **self.who(access, user),
            "key": access, "cmd": req.get("cmd"), "args": _args_of(request), "id": req.get("id"),
            "ok": ok, "error": None if ok else str(reply.get("error", ""))}
        with self._lock:
            counts = self._applied if ok else self._refused
            counts[vehicle] = counts.get(vehicle, 0) + 1
            self._last.setdefault(vehicle, deque(maxlen=KEEP_LAST)).append(rec)
        log.log(logging.INFO if ok and rec["cmd"] not in READ_ONLY else logging.DEBUG if ok
                else logging.WARNING, "%s: command %s by %s (%s key): %s", vehicle, rec["cmd"],
                rec["user"], access, "applied" if ok else f"refused: {rec['error']}")
        try:
            self._publish(prefix + "cmd_log", msgpack.packb(rec, use_bin_type=True))
        except Exception as exc:  # a closed session must not fail the command
            log.warning("%s: cannot publish cmd_log: %s", vehicle, exc)
        return rec

    def summary(self, vehicle: str) -> dict[str, Any]:
        """``{"applied", "refused", "last": [records]}`` of one vehicle (diag and status)."""
        with self._lock:
            return {"applied": self._applied.get(vehicle, 0), "refused": self._refused.get(vehicle, 0),
                    "last": list(self._last.get(vehicle, ()))}


def _args_of(request: Any) -> dict[str, Any] | None:
    """The request's arguments (everything but cmd, v, id) as sent, or only their names if
    they pack to more than :data:`ARGS_MAX_BYTES`."""
    if not isinstance(request, dict):
        return None
    args = {str(k): v for k, v in request.items() if k not in ("cmd", "v", "id")}
    try:
        if len(msgpack.packb(args, use_bin_type=True)) <= ARGS_MAX_BYTES:
            return args
    except (TypeError, ValueError, OverflowError):
        pass
    return {"truncated": sorted(args)}


def handle_query(v: Any, key: str, data: bytes, gate: AuditLog,
                 submit: Callable[[Any, commands.Command], dict[str, Any]]) -> dict[str, Any]:
    """One command query of vehicle ``v`` on ``key``: decode, authorize, parse, ``submit`` to the
    filter loop (returns its reply), audit. The reply map."""
    access, user = command_access(v.prefix, key)
    request: dict[str, Any] | None = None
    try:
        request = commands.decode(data)
        refusal = authorize(access, user, str(request.get("cmd")), gate.profile)
        if refusal is not None:
            exc = commands.CommandError(refusal)
            exc.cmd, exc.id = request.get("cmd"), request.get("id")
            raise exc
        cmd = commands.parse(request, v.sp.engine.n_gyro)
    except commands.CommandError as exc:
        reply = commands.error_reply(str(exc), exc)
    else:
        reply = submit(v, cmd)
    gate.record(v.name, v.prefix, access, user, request, reply)
    return reply
