"""The one place where Zenoh session configurations are made (eclipse-zenoh 1.x).

Rules (workplace and CONTRACT §5): multicast scouting is always off; endpoints are explicit
``tcp/127.0.0.1:PORT`` loopback locators. With neither ``listen`` nor ``connect`` given, a session
uses the documented loopback default: the node listens on :data:`DEFAULT_ENDPOINT`, every other tool
(replay, record, monitors) connects to it. A Zenoh JSON5 file may override anything
(``--zenoh-config FILE``), and the loopback/multicast rules are then checked, not assumed.
"""

from __future__ import annotations

import json
import re
import socket
from collections.abc import Sequence
from typing import Any

DEFAULT_PORT = 7448
DEFAULT_ENDPOINT = f"tcp/127.0.0.1:{DEFAULT_PORT}"
_LOOPBACK = re.compile(r"^(?:tcp|tls)/(127\.\d{1,3}\.\d{1,3}\.\d{1,3}|localhost|\[::1\]):(\d{1,5})$")


class ZenohConfigError(ValueError):
    """An endpoint or configuration that breaks the loopback-only rule, or is malformed."""


def check_endpoint(ep: str) -> str:
    """Return ep if it is a loopback TCP or TLS locator (tcp/127.x.x.x:PORT, tcp/localhost:PORT,
    tls/127.0.0.1:PORT)."""
    m = _LOOPBACK.match(ep) if isinstance(ep, str) else None
    if m is None:
        raise ZenohConfigError(f"endpoint {ep!r} is not a loopback locator like tcp/127.0.0.1:7448 "
                                "(or tls/127.0.0.1:7448)")
    if not 1 <= int(m.group(2)) <= 65535:
        raise ZenohConfigError(f"endpoint {ep!r}: port must be 1..65535, got {int(m.group(2))}")
    return ep


def make_config(mode: str = "peer", listen: Sequence[str] = (), connect: Sequence[str] = (),
                extra: dict[str, Any] | None = None, config_file: str | None = None):
    """A zenoh.Config with explicit loopback endpoints and multicast scouting off.

    mode: "peer" | "client" | "router". listen/connect: loopback locators. extra: key path →
    value inserted with insert_json5. config_file: a Zenoh JSON5 file loaded first.
    """
    import zenoh

    if mode not in ("peer", "client", "router"):
        raise ZenohConfigError(f"mode must be peer, client or router, got {mode!r}")
    cfg = zenoh.Config.from_file(config_file) if config_file else zenoh.Config()
    cfg.insert_json5("mode", json.dumps(mode))
    cfg.insert_json5("listen/endpoints", json.dumps([check_endpoint(e) for e in listen]))
    cfg.insert_json5("connect/endpoints", json.dumps([check_endpoint(e) for e in connect]))
    cfg.insert_json5("scouting/multicast/enabled", "false")
    for key, value in (extra or {}).items():
        cfg.insert_json5(key, json.dumps(value))
    return cfg


def free_port() -> int:
    """A currently free TCP port on 127.0.0.1 (for tests and ad-hoc sessions)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def endpoints(listen: str | None, connect: str | None, role: str,
              default: str | None = None) -> tuple[list[str], list[str]]:
    """Resolve --listen/--connect for a tool: role "node" listens on the default, others connect
    to it. default: the endpoint used when neither is given (None: :data:`DEFAULT_ENDPOINT`; a
    security profile's own endpoint, e.g. ``tls/127.0.0.1:7448``)."""
    if listen or connect:
        return ([listen] if listen else []), ([connect] if connect else [])
    ep = default or DEFAULT_ENDPOINT
    return ([ep], []) if role == "node" else ([], [ep])
