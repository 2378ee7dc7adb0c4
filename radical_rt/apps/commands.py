"""Commands of the filter node (CONTRACT §3.2): parsed in the query callback, applied in the loop.

Request: msgpack map ``{"cmd": NAME, ...}`` on ``radical/<vehicle>/cmd``. Reply: ``{"ok": true,
"cmd": NAME, ...}`` or ``{"ok": false, "error": "clear message"}``. An optional ``"id"`` is echoed
back; ``"v"`` is accepted and ignored; any other unknown field is an error (a typo must not be
mistaken for a no-op).

Two phases, so that a Zenoh callback never touches filter state:

* :func:`parse` (query callback thread) decodes and validates everything that does not depend on
  the engine's state and returns a :class:`Command`, or raises :class:`CommandError`;
* :func:`apply` (the node's filter loop, between two filter steps) checks what does depend on the
  state (e.g. at least three gyros stay included), then mutates. It raises :class:`CommandError`
  before any change, so an invalid command changes nothing.

The commands, their arguments (SI unless named with a paper unit) and their reply fields are
listed in docs/node.md, "Commands": status, get_params, set_params, reset_params, bump,
warm_start, cold_start, exclude_gyro, include_gyro, set_packets, checkpoint, end_stream
(:data:`COMMANDS` maps each name to its parser and applier).

Every argument has a valid range (docs/node.md, "Valid ranges"): parameters
:data:`radical_rt.contract.params.RANGES`, bump 1σ at most :data:`BUMP_MAX_SI` per group, packet settings
:func:`radical_rt.stream.telemetry.parse_packets`. ``id`` is a string of at most 128 characters or an
integer. A refused command changes nothing and its error names the value and why.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import msgpack
import numpy as np

from radical_rt.contract.conventions import PAPER_UNITS, from_paper_units, to_paper_units
from radical_rt.contract.params import GROUP_BUMP, RANGES, ParamError, ParamTable
from radical_rt.contract.state import PARAM_GROUPS, StateLayout
from radical_rt.kernels import ud_time
from radical_rt.stream.processor import StreamProcessor
from radical_rt.stream.telemetry import PacketError, PacketSpec, parse_packets

_COMMON = {"cmd", "v", "id"}
#: largest 1σ a bump may add per group [SI] (the table's bump_* ranges, :data:`params.RANGES`)
BUMP_MAX_SI = {g: from_paper_units(g, RANGES[name][1]) for g, name in GROUP_BUMP.items()}
#: group → its name with the paper unit at the command interface (the table's bump_* name less
#: "bump_"): b_deg_hr, lam_ppm, mu_ppm, du_arcsec, dv_arcsec, phi2_arcsec
BUMP_NAME = {g: name[len("bump_"):] for g, name in GROUP_BUMP.items()}
_BUMP_GROUP = {n: g for g, n in BUMP_NAME.items()}


class CommandError(ValueError):
    """An invalid command; the message is the reply's ``error``. ``cmd``/``id``: of the request,
    when known, echoed in the error reply."""

    cmd: str | None = None
    id: Any = None


@dataclass
class Command:
    """A parsed, validated command: name, normalized arguments, optional request id."""

    name: str
    args: dict[str, Any] = field(default_factory=dict)
    id: Any = None


class Target(Protocol):
    """What a command acts on: one vehicle of the node (see :class:`radical_rt.apps.node_vehicle.Vehicle`)."""

    sp: StreamProcessor

    def status(self) -> dict[str, Any]: ...

    def write_checkpoint(self) -> str: ...

    def end_stream(self, next_start: str | None) -> dict[str, Any]: ...


# ------------------------------------------------------------------------------------ parsing
def decode(payload: bytes) -> dict[str, Any]:
    """msgpack request → map with a string ``cmd``; CommandError otherwise."""
    try:
        req = msgpack.unpackb(bytes(payload), raw=False, strict_map_key=False)
    except Exception as exc:
        raise CommandError(f"request is not valid msgpack: {exc}") from None
    if not isinstance(req, dict):
        raise CommandError(f"request must be a msgpack map, got {type(req).__name__}")
    name = req.get("cmd")
    if not isinstance(name, str):
        raise CommandError(f"request needs a string 'cmd'; known: {', '.join(COMMANDS)}")
    return req


def parse(payload: bytes | dict, n_gyro: int = 4) -> Command:
    """Decode and validate a request (no engine state needed). Raises CommandError."""
    req = payload if isinstance(payload, dict) else decode(payload)
    name = req.get("cmd")
    if name not in COMMANDS:
        raise CommandError(f"unknown command {name!r}; known: {', '.join(COMMANDS)}")
    allowed, parser, _ = COMMANDS[name]
    rid = req.get("id")
    if rid is not None and not (isinstance(rid, str) and len(rid) <= 128 or isinstance(rid, int)
                                and not isinstance(rid, bool)):
        exc = CommandError(f"{name}: 'id' must be a string of at most 128 characters or an integer")
        exc.cmd = name
        raise exc
    try:
        unknown = sorted(str(k) for k in set(req) - _COMMON - set(allowed))
        if unknown:
            hint = f"; {name} takes {', '.join(allowed)}" if allowed else f"; {name} takes no arguments"
            raise CommandError(f"{name}: unknown field(s) {unknown}{hint}")
        args = parser({k: req[k] for k in allowed if k in req}, n_gyro)
    except CommandError as exc:
        exc.cmd, exc.id = name, req.get("id")
        raise
    return Command(name, args, req.get("id"))


def _no_args(a: dict, n: int) -> dict:
    return {}


def _p_set_params(a: dict, n: int) -> dict:
    params = a.get("params")
    if not isinstance(params, dict) or not params:
        raise CommandError("set_params: 'params' must be a non-empty map of name → value")
    try:
        ParamTable(n_gyro=n).set(params)  # validation only (types, shapes, ranges)
    except ParamError as exc:
        raise CommandError(f"set_params: {exc}") from None
    return {"params": params}


def _number_list(where: str, values: Any, size: int, hi: float, unit: str) -> list[float]:
    if not isinstance(values, (list, tuple)) or len(values) != size:
        raise CommandError(f"{where}: expected a list of {size} numbers, got {_short(values)}")
    for v in values:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not _in(v, 0.0, hi):
            raise CommandError(f"{where}: values must be numbers in [0, {hi:g}] ({unit}), "
                               f"got {_short(v)}")
    return [float(v) for v in values]


def _in(v: int | float, lo: float, hi: float) -> bool:
    """lo ≤ v ≤ hi for a finite v (ints beyond float range are out)."""
    try:
        return math.isfinite(float(v)) and lo <= float(v) <= hi
    except OverflowError:
        return False


def _short(value: Any) -> str:
    r = repr(value)
    return r if len(r) <= 60 else r[:57] + "..."


def _p_bump(a: dict, n: int) -> dict:
    """sigma {paper-unit name: [1σ]} (or a bare group name: SI) → {group: [1σ, SI]}."""
    names = ", ".join(BUMP_NAME.values())
    sigma = a.get("sigma")
    if not isinstance(sigma, dict) or not sigma:
        raise CommandError(f"bump: 'sigma' must be a non-empty map name → [1σ values]; names: "
                           f"{names} (or a bare group name with SI values)")
    layout = StateLayout(n)
    out = {}
    for key, values in sigma.items():
        group = _BUMP_GROUP.get(key, key)
        if group not in PARAM_GROUPS:
            raise CommandError(f"bump: unknown group {key!r}; names: {names} (or a bare group "
                               f"name with SI values: {', '.join(PARAM_GROUPS)})")
        if group in out:
            raise CommandError(f"bump: group {group!r} given twice ({BUMP_NAME[group]} and "
                               f"{group})")
        size, where = layout.block(group).size, f"bump: sigma.{key}"
        if key == group:  # CONTRACT §3.2's form: SI
            out[group] = _number_list(where, values, size, BUMP_MAX_SI[group], "SI")
        else:
            hi = RANGES[GROUP_BUMP[group]][1]
            out[group] = [from_paper_units(group, v) for v in _number_list(
                where, values, size, hi, PAPER_UNITS[group])]
    mode = a.get("mode")
    if mode is not None and mode not in ("add", "scale"):
        raise CommandError(f"bump: mode must be 'add' or 'scale', got {mode!r}")
    return {"sigma": out, "mode": mode}


def _p_warm(a: dict, n: int) -> dict:
    bump = a.get("bump", True)
    if not isinstance(bump, bool):
        raise CommandError(f"warm_start: bump must be true or false, got {bump!r}")
    return {"bump": bump}


def _p_gyro(a: dict, n: int) -> dict:
    g = a.get("gyro")
    if isinstance(g, bool) or not isinstance(g, int) or not 0 <= g < n:
        raise CommandError(f"'gyro' must be an integer 0..{n - 1}, got {g!r}")
    return {"gyro": g}


def _p_packets(a: dict, n: int) -> dict:
    doc = a.get("packets")
    if not isinstance(doc, dict) or not doc:
        raise CommandError("set_packets: 'packets' must be a non-empty map like the TOML "
                           "[packets] table, e.g. {\"small\": {\"period_s\": 0.2}}")
    try:
        specs = parse_packets(doc)
    except PacketError as exc:
        raise CommandError(f"set_packets: {exc}") from None
    return {"packets": specs}


def _p_end(a: dict, n: int) -> dict:
    nxt = a.get("next", "warm")
    if nxt not in ("warm", "cold", "none"):
        raise CommandError(f"end_stream: next must be 'warm', 'cold' or 'none', got {nxt!r}")
    return {"next": None if nxt == "none" else nxt}


# ------------------------------------------------------------------------------------ applying
def apply(cmd: Command, target: Target) -> dict[str, Any]:
    """Apply a parsed command between filter steps; the reply map. CommandError = no change."""
    reply = {"ok": True, "cmd": cmd.name, **COMMANDS[cmd.name][2](cmd.args, target)}
    if cmd.id is not None:
        reply["id"] = cmd.id
    return reply


def error_reply(message: str, cmd: Command | CommandError | None = None) -> dict[str, Any]:
    """``{"ok": false, "error": message}`` plus the request's cmd and id when known."""
    out: dict[str, Any] = {"ok": False, "error": message}
    name = cmd.name if isinstance(cmd, Command) else cmd.cmd if cmd is not None else None
    if name is not None:
        out["cmd"] = name
        if cmd.id is not None:  # type: ignore[union-attr]
            out["id"] = cmd.id  # type: ignore[union-attr]
    return out


def _a_status(a: dict, t: Target) -> dict:
    return t.status()


def _a_get_params(a: dict, t: Target) -> dict:
    table = t.sp.engine.table
    return {"params": table.as_dict("active"), "default": table.as_dict("default")}


def _a_set_params(a: dict, t: Target) -> dict:
    _table_change(t.sp.engine, "set_params", lambda table: table.set(a["params"]))
    active = t.sp.engine.table.as_dict("active")
    return {"params": {k: active[k] for k in a["params"]}}


def _a_reset_params(a: dict, t: Target) -> dict:
    _table_change(t.sp.engine, "reset_params", lambda table: table.reset())
    return {"params": t.sp.engine.table.as_dict("active")}


def _table_change(e: Any, where: str, change: Any) -> None:
    """Change the active table and let the engine re-read it, all-or-nothing: if the change or
    the engine's derived configuration (SI table, FDI thresholds) fails, the previous table is
    put back and re-read, and CommandError says why (nothing changed)."""
    old = copy.deepcopy(e.table.active)
    try:
        change(e.table)
        e.params_changed()
        if getattr(e, "fdi", None) is not None:  # the thresholds must be computable
            e.fdi.detector(e)
    except Exception as exc:  # noqa: BLE001 - whatever failed, the old table comes back
        e.table.active = old
        e.params_changed()
        raise CommandError(f"{where}: {exc} (nothing changed)") from None


def _a_bump(a: dict, t: Target) -> dict:
    """The bump is tried first on copies of the UD factors (:func:`_bump_dry_run`): one that
    would not leave valid factors is refused and changes nothing."""
    e = t.sp.engine
    mode = a["mode"] or e.si.bump_mode
    why = _bump_dry_run(e, a["sigma"], mode)
    if why:
        raise CommandError(f"bump: {why} (nothing changed)")
    e.bump(a["sigma"], mode)
    return {"sigma": {BUMP_NAME[g]: [float(to_paper_units(g, v)) for v in vals]
                      for g, vals in e.sigmas().items() if g in BUMP_NAME}, "mode": mode}


#: a "scale" bump may multiply a σ by at most this (larger factors break the conditioning of U)
BUMP_SCALE_MAX = 1e6


def _bump_dry_run(e: Any, sigma: dict[str, list[float]], mode: str) -> str:
    """Why the bump would not leave finite UD factors with d > 0 ("" if it would)."""
    U, d = e.U.copy(), e.d.copy()
    if mode == "add":
        idx = [e.layout[g].start + k for g, v in sigma.items() for k in range(len(v))]
        c = [float(x) ** 2 for v in sigma.values() for x in v]
        status = ud_time.add_diagonal_noise(U, d, np.asarray(idx, np.int64), np.asarray(c),
                                       np.zeros(e.ns))
    else:
        var = e.variances()
        s = np.ones(e.ns)
        for g, v in sigma.items():
            sl = e.layout[g]
            with np.errstate(all="ignore"):
                s[sl] = np.sqrt(1.0 + np.asarray(v, float) ** 2 / var[sl])
        if not (np.all(np.isfinite(s)) and s.max() <= BUMP_SCALE_MAX):
            return f"a scale factor would exceed {BUMP_SCALE_MAX:g}"
        status = ud_time.scale_states(U, d, s)
    if status != 0 or not (np.all(np.isfinite(U)) and np.all(np.isfinite(d)) and np.all(d > 0)):
        return f"the bumped covariance would not be numerically valid (UD status {status})"
    return ""


def _a_warm(a: dict, t: Target) -> dict:
    t.sp.engine.warm_start(bump=a["bump"])
    return {"mode": t.sp.engine.mode}


def _a_cold(a: dict, t: Target) -> dict:
    t.sp.engine.cold_start()
    return {"mode": t.sp.engine.mode}


def _excluded(e: Any) -> list[int]:
    return [int(i) for i, x in enumerate(e.excluded) if x]


def _a_exclude(a: dict, t: Target) -> dict:
    e, g = t.sp.engine, a["gyro"]
    if not e.excluded[g] and e.n_gyro - int(e.excluded.sum()) - 1 < 3:
        raise CommandError(f"exclude_gyro: cannot exclude gyro {g}: at least 3 gyros must stay "
                           f"included (excluded now: {_excluded(e)})")
    e.excluded[g] = True
    return {"excluded": _excluded(e)}


def _a_include(a: dict, t: Target) -> dict:
    e = t.sp.engine
    e.excluded[a["gyro"]] = False
    if getattr(e, "fdi", None) is not None:  # an operator override also clears GYRO_<i>_FAILED
        e.fdi.on_include(e, a["gyro"])
    return {"excluded": _excluded(e)}


def _a_packets(a: dict, t: Target) -> dict:
    old, new = t.sp.packets, a["packets"]
    for name, spec in new.items():  # sequence numbers continue
        if name in old:
            spec.seq = old[name].seq
    t.sp.packets = new
    return {"packets": packets_config(new)}


def packets_config(specs: dict[str, PacketSpec]) -> dict[str, dict[str, Any]]:
    """The [packets] map of a packet configuration (what set_packets / the TOML file take)."""
    out: dict[str, dict[str, Any]] = {}
    for name, s in specs.items():
        d: dict[str, Any] = {"fields": list(s.fields)}
        if s.decimation is not None:
            d["decimation"] = s.decimation
        else:
            d["period_s"] = s.period_s
        d["trigger"] = s.trigger
        out[name] = d
    return out


def _a_checkpoint(a: dict, t: Target) -> dict:
    return {"path": t.write_checkpoint()}


def _a_end(a: dict, t: Target) -> dict:
    return t.end_stream(a["next"])


#: name → (allowed argument fields, parser(args, n_gyro) → args, applier(args, target) → reply)
COMMANDS: dict[str, tuple[tuple[str, ...], Any, Any]] = {
    "status": ((), _no_args, _a_status),
    "get_params": ((), _no_args, _a_get_params),
    "set_params": (("params",), _p_set_params, _a_set_params),
    "reset_params": ((), _no_args, _a_reset_params),
    "bump": (("sigma", "mode"), _p_bump, _a_bump),
    "warm_start": (("bump",), _p_warm, _a_warm),
    "cold_start": ((), _no_args, _a_cold),
    "exclude_gyro": (("gyro",), _p_gyro, _a_exclude),
    "include_gyro": (("gyro",), _p_gyro, _a_include),
    "set_packets": (("packets",), _p_packets, _a_packets),
    "checkpoint": ((), _no_args, _a_checkpoint),
    "end_stream": (("next",), _p_end, _a_end),
}
