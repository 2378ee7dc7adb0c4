"""Zenoh sessions of the tools (`radical replay`, `radical record`) and the node's liveliness.

:func:`tool_config` builds a tool's Zenoh configuration (peer when it listens, client of the
endpoint when it only connects), :func:`open_session` opens it (a client retries until its
endpoint is up), :func:`wait_for_node` / :func:`served_vehicles` look for the filter node's
liveliness token ``radical/<vehicle>/alive/filter`` (CONTRACT §2). Errors are
:class:`ReplayError` (one line). Times are monotonic seconds.
"""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Callable
from typing import Any

VEHICLE_RE = re.compile(r"^[a-z0-9_-]+$")
SLICE_S = 0.2  # longest uninterrupted sleep of a tool: a stop request is seen within this


class ReplayError(Exception):
    """A replay cannot start or go on; ``str(e)`` is one line."""


def node_token_key(vehicle: str) -> str:
    """The filter node's liveliness token for ``vehicle`` (CONTRACT §2)."""
    return f"radical/{vehicle}/alive/filter"


def check_vehicle(vehicle: str) -> str:
    """``vehicle`` if it is a valid vehicle name ([a-z0-9_-]+, CONTRACT §2), else ReplayError."""
    if not isinstance(vehicle, str) or not VEHICLE_RE.match(vehicle):
        raise ReplayError(f"vehicle {vehicle!r} must match [a-z0-9_-]+")
    return vehicle


def tool_config(listen: str | None, connect: str | None, role: str,
                config_file: str | None = None, auth: Any = None) -> tuple[Any, str, str]:
    """``(zenoh.Config, mode, description)`` for a tool (replay, record).

    Endpoints are ``zconfig.endpoints`` (neither option: connect to the node's default). A tool
    that listens is a peer; a tool that only connects is a **client** of that endpoint: the node
    is a peer, and a peer routes for its clients but does not relay between two peers that both
    only connect to it, so two peer tools (``radical replay`` → ``radical record``) would not see
    each other through the node.

    ``auth``: a :class:`radical_rt.io.zauth.SessionAuth` (``--auth DIR --role ROLE``): the
    profile's endpoint by default and the user's credentials; such a tool only connects (the
    node or a router is the enforcement point), ZenohConfigError if it would listen."""
    from radical_rt.io import zconfig

    lst, con = zconfig.endpoints(listen, connect, role=role,
                                 default=auth.profile.endpoint if auth is not None else None)
    if auth is not None and lst:
        raise zconfig.ZenohConfigError("with --auth a tool connects to the node or a router "
                                       "(--connect), it does not --listen")
    mode = "peer" if lst else "client"
    cfg = zconfig.make_config(mode, listen=lst, connect=con, config_file=config_file,
                              extra=auth.settings(listening=False) if auth is not None else None)
    where = ", ".join([f"listening on {e}" for e in lst] + [f"connecting to {e}" for e in con])
    return cfg, mode, where


def open_session(cfg: Any, mode: str, deadline: float | None = None,
                 stop_event: threading.Event | None = None,
                 on_retry: Callable[[str], None] | None = None) -> Any:
    """``zenoh.open(cfg)``. A client cannot open before its endpoint is up: it retries every
    0.2 s until ``deadline`` (monotonic s; None: one attempt; ``math.inf``: until
    ``stop_event``), calling ``on_retry(error)`` after each failure. ReplayError when it gives up."""
    import zenoh

    while True:
        try:
            return zenoh.open(cfg)
        except Exception as e:  # zenoh.ZError
            err = " ".join(str(e).split(" at /")[0].split())
            if mode != "client" or deadline is None:
                raise ReplayError(f"cannot open a Zenoh {mode} session: {err}") from None
            if on_retry is not None:
                on_retry(err)
            if stop_event is not None and stop_event.is_set():
                raise ReplayError(f"stopped before connecting ({err})") from None
            if time.monotonic() + 0.2 > deadline:
                raise ReplayError(f"cannot connect: {err}") from None
            if stop_event is not None:
                stop_event.wait(0.2)
            else:
                time.sleep(0.2)


def wait_for_node(session: Any, vehicle: str, timeout: float,
                  stop_event: threading.Event | None = None) -> float:
    """Block until the node's liveliness token ``radical/<vehicle>/alive/filter`` is alive
    (already present or appearing later). Returns the wait (s); ReplayError on timeout."""
    import zenoh

    key, seen = node_token_key(check_vehicle(vehicle)), threading.Event()

    def on_token(sample: Any) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            seen.set()

    t0 = time.monotonic()
    sub = session.liveliness().declare_subscriber(key, on_token, history=True)
    try:
        while not seen.wait(min(SLICE_S, max(t0 + timeout - time.monotonic(), 0.0))):
            if stop_event is not None and stop_event.is_set():
                raise ReplayError("stopped while waiting for the node")
            if time.monotonic() >= t0 + timeout:
                raise ReplayError(f"no filter node for vehicle {vehicle!r}: liveliness token "
                                  f"{key} not seen within {timeout:g} s")
    finally:
        sub.undeclare()
    return time.monotonic() - t0


def served_vehicles(session: Any, timeout: float = 1.0) -> list[str]:
    """Vehicles whose node liveliness token ``radical/<V>/alive/filter`` is alive now (sorted;
    [] if the query fails)."""
    try:
        replies = session.liveliness().get("radical/*/alive/filter", timeout=timeout)
        keys = {str(r.ok.key_expr) for r in replies if r.ok is not None}
    except Exception:  # noqa: BLE001 - a diagnostic only
        return []
    return sorted(k.split("/")[1] for k in keys if k.count("/") == 3)
