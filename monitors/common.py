"""Display helpers shared by the report and the live monitors.

Everything here works on the contract's messages (CONTRACT §3: plain dicts decoded from msgpack)
and converts to the paper's units with :mod:`radical_rt.contract.conventions`. No filter internals.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from typing import Any

from radical_rt.contract.conventions import ARCSEC, PAPER_UNITS, SI_PER_PAPER_UNIT
from radical_rt.contract.flags import Flag, flag_names
from radical_rt.contract.paper_table import DIGITS, ORDER, TITLES, element_names

__all__ = ["ARCSEC", "DIGITS", "FLAG_BITS", "GROUP_LABELS", "ORDER", "PAPER_UNITS", "TITLES",
           "element_names", "flag_names", "flag_label", "fmt_est_sigma", "group_paper",
           "residual_kinds", "safe_name", "TABLE_NUMBER", "VEHICLE_RE", "vehicle_of"]

#: Paper table number per parameter group (Tables 2–7).
TABLE_NUMBER = {"phi2": 2, "b": 3, "lam": 4, "mu": 5, "du": 6, "dv": 7}
#: Short display names of the groups (paper symbols).
GROUP_LABELS = {"b": "b", "lam": "λ", "mu": "μ", "du": "δu", "dv": "δv", "phi2": "δa2 (ST2)"}
#: (bit, name) of every known flag (CONTRACT §3.1), bit order.
FLAG_BITS: list[tuple[int, str]] = [(int(f).bit_length() - 1, f.name or "") for f in Flag]
VEHICLE_RE = re.compile(r"^[a-z0-9_-]+$")


def flag_label(bits: int | None) -> str:
    """``"ST2_EDITED, NOT_CONVERGED"``, ``"-"`` for none; unknown bits (16 and up) as ``BIT<n>``."""
    if bits is None:
        return "?"
    bits = int(bits)
    names = flag_names(bits)
    known = 0
    for f in Flag:
        known |= int(f)
    extra = bits & ~known
    names += [f"BIT{i}" for i in range(extra.bit_length()) if extra >> i & 1]
    return ", ".join(names) if names else "-"


def group_paper(group: str, values: Iterable[Any] | None) -> list[float]:
    """SI list → paper units (deg/hr, ppm, arcsec); None/non-numbers become NaN."""
    if values is None:
        return []
    k = SI_PER_PAPER_UNIT[group]
    out = []
    for v in values:
        try:
            out.append(float(v) / k)
        except (TypeError, ValueError):
            out.append(math.nan)
    return out


def fmt_est_sigma(group: str, est: float, sigma: float | None) -> str:
    """``"0.5033 ± 0.0013"`` with the paper's digits for the group."""
    dg = DIGITS.get(group, 2)
    if est is None or not math.isfinite(est):
        return "—"
    s = f"{est:.{dg}f}"
    if sigma is not None and math.isfinite(sigma):
        s += f" ± {sigma:.{dg + 1}f}"
    return s


def residual_kinds(residuals: dict[str, Any] | None) -> list[str]:
    """The residual kinds of a tlm/large ``residuals`` map in display order (st1, st2, parity)."""
    if not isinstance(residuals, dict):
        return []
    order = ["st1", "st2", "parity"]
    return [k for k in order if k in residuals] + sorted(k for k in residuals if k not in order)


def safe_name(label: str) -> str:
    """A label made safe for a file name."""
    s = re.sub(r"[^A-Za-z0-9_.-]+", "_", label).strip("._")
    return s or "archive"


def vehicle_of(key: str) -> tuple[str, str] | None:
    """``radical/<vehicle>/<topic>`` → (vehicle, topic); None for other keys."""
    parts = str(key).split("/", 2)
    if len(parts) < 3 or parts[0] != "radical" or not VEHICLE_RE.match(parts[1]):
        return None
    return parts[1], parts[2]


def excitation_text(ex: dict | None) -> str:
    """One line from diag's ``excitation`` map (docs/contract_extensions.md): the window, the
    rotation in it, the information gain per group (ln σ ratio), and the groups not excited."""
    if not ex:
        return ""
    gains = " ".join(f"{g} {v['gain']:+.2f}" for g, v in ex["groups"].items())
    bad = ex.get("not_excited") or []
    tail = f"  NOT EXCITED: {', '.join(bad)}" if bad else ""
    if ex.get("rotate_about"):
        tail += f"  (axes not yet turned about: {', '.join(ex['rotate_about'])})"
    return f"{ex['window_s']:.0f} s, rotated {ex['rotation_deg']:.1f}°; gain {gains}{tail}"


def monitor_config(listen: str | None, connect: str | None, zenoh_config: str | None,
                   auth: Any = None) -> Any:
    """The zenoh.Config of a live monitor: loopback endpoints (neither: connect to the node's
    default), multicast off; ``auth`` (a ``radical_rt.io.zauth.SessionAuth``): a client of the
    profile's endpoint with the user's credentials (a monitor never listens then)."""
    from radical_rt.io import zconfig

    default = auth.profile.endpoint if auth is not None else None
    listen_eps, connect_eps = zconfig.endpoints(listen, connect, role="monitor", default=default)
    if auth is None:
        return zconfig.make_config("peer", listen=listen_eps, connect=connect_eps,
                                   config_file=zenoh_config)
    if listen_eps:
        raise zconfig.ZenohConfigError("with --auth a monitor connects to the node or a router "
                                       "(--connect), it does not --listen")
    return zconfig.make_config("client", connect=connect_eps, config_file=zenoh_config,
                               extra=auth.settings(listening=False))
