"""JSON Schemas for Foxglove / Lichtblick: inferred from the messages, described with units.

Foxglove and Lichtblick turn a ``jsonschema`` channel schema into message datatypes (Lichtblick
``packages/mcap-support/src/parseJsonSchema.ts``) and accept only this subset: every schema and
sub-schema of an object is ``"type": "object"`` with ``properties``; every property has one
``type`` string among object, array, number, integer, boolean, string; array items are a single
schema of one of those types *except array* (no arrays of arrays). ``const``- or ``enum``-only
properties and ``$ref`` are rejected. The schemas made here keep to that subset.

:class:`SchemaBuilder` merges the shapes of observed messages (``observe``) and returns a schema
(``schema``) whose descriptions come from the archive's contract schemas
(``radical_rt.contract.schemas``, units in every description) or, for fields the contract leaves free (``diag``, ``fault.detail``,
counters, clock), from the field's name (``*_s`` s, ``*_ppm`` ppm, ``*_C`` °C, ``nis``
dimensionless, …). Values inside are SI unless the name or description says otherwise.

Also here: the Foxglove well-known schemas written by hand (``foxglove.FrameTransform``,
``foxglove.Log``; the tests validate our messages against the copies Foxglove publishes in
``@foxglove/schemas``) and the paper-units channel schema.
"""

from __future__ import annotations

import copy
import re
from typing import Any

_UNIT_RULES: list[tuple[str, str]] = [  # (regex on the field name, description)
    (r"_s$|^t$|^t_|_time$|^period|latency", "time or duration (s)"),
    (r"_ms$", "duration (ms)"),
    (r"_ns$", "time (ns)"),
    (r"_ppm$|ppm", "parts per million (ppm)"),
    (r"_C$", "temperature (degrees Celsius)"),
    (r"nis", "normalized innovation squared (dimensionless, chi-square distributed)"),
    (r"^innov", "innovation: measured minus predicted (rad)"),
    (r"sigma", "1-sigma uncertainty (SI: rad, rad/s or dimensionless as the quantity)"),
    (r"^q_|^q$", "quaternion, scalar-last [x, y, z, w] (dimensionless)"),
    (r"omega|rate", "angular rate (rad/s)"),
    (r"dtheta|angle|phi|att", "angle (rad)"),
    (r"count|^n_|_used$|_edited$|_rejected$|_missing$|_repeated$|samples|wraps|resets", "count"),
    (r"flags", "fault flag bits (CONTRACT §3.1; bit names in the flag_names or set/cleared fields)"),
    (r"mode|state", "mode name"),
]


def describe_name(name: str) -> str:
    """A unit description guessed from a field name (SI by default)."""
    for pat, text in _UNIT_RULES:
        if re.search(pat, name, re.IGNORECASE):
            return f"{name}: {text}"
    return f"{name} (SI units: rad, rad/s, s, unless stated otherwise)"


def _kind(v: Any) -> str | None:
    if isinstance(v, bool):
        return "boolean"
    if isinstance(v, int):
        return "integer"
    if isinstance(v, float):
        return "number"
    if isinstance(v, str):
        return "string"
    if isinstance(v, list | tuple):
        return "array"
    if isinstance(v, dict):
        return "object"
    return None  # None (omitted in the export) or an unknown type


class _Node:
    """The merged shape of the values seen at one path."""

    __slots__ = ("kind", "props", "items")

    def __init__(self) -> None:
        self.kind: str | None = None
        self.props: dict[str, _Node] = {}
        self.items: _Node | None = None

    def add(self, v: Any) -> None:
        k = _kind(v)
        if k is None:
            return
        if self.kind is None:
            self.kind = k
        elif self.kind != k:
            if {self.kind, k} == {"integer", "number"}:
                self.kind = "number"
            else:  # a conflict (never seen in our messages): strings carry anything
                self.kind, self.props, self.items = "string", {}, None
                return
        if k == "object" and self.kind == "object":
            for key, val in v.items():
                self.props.setdefault(str(key), _Node()).add(val)
        elif k == "array" and self.kind == "array":
            if self.items is None:
                self.items = _Node()
            for x in v:
                self.items.add(x)


def _known_sub(known: dict[str, Any] | None, key: str) -> dict[str, Any] | None:
    if not isinstance(known, dict):
        return None
    sub = (known.get("properties") or {}).get(key)
    return sub if isinstance(sub, dict) else None


def _render(node: _Node, name: str, known: dict[str, Any] | None,
            parent: str = "") -> dict[str, Any]:
    kind = node.kind or (known.get("type") if known and isinstance(known.get("type"), str)
                         else "number")
    desc = (known or {}).get("description")
    if not desc:
        if kind == "boolean":
            desc = f"{name}: true/false"
        elif kind == "integer" and "counter" in parent:
            desc = f"{name}: count"
        else:
            desc = describe_name(name)
    out: dict[str, Any] = {"type": kind, "description": desc}
    if kind == "object":
        props = {}
        for key, child in node.props.items():
            props[key] = _render(child, key, _known_sub(known, key), name)
        out["properties"] = props
    elif kind == "array":
        item_known = (known or {}).get("items")
        items = node.items or _Node()
        if items.kind is None:
            items.kind = "number"
        out["items"] = _render(items, name + "[]", item_known if isinstance(item_known, dict)
                               else None)
    return out


class SchemaBuilder:
    """Merge observed messages of one channel into a Foxglove-compatible JSON Schema.

    ``known``: the contract schema of the topic (or None); ``title``/``description``: of the
    channel. Observed messages must already be JSON-ready (:func:`monitors.fox_convert.jsonable`).
    """

    def __init__(self, title: str, description: str, known: dict[str, Any] | None = None) -> None:
        self.title, self.description = title, description
        self.known = known
        self._root = _Node()
        self.count = 0

    def observe(self, msg: dict[str, Any]) -> None:
        self._root.add(msg)
        self.count += 1

    def schema(self) -> dict[str, Any]:
        """The schema (draft 2020-12 keywords; an object with properties, no refs)."""
        root = self._root if self._root.kind == "object" else _Node()
        if root.kind is None:
            root.kind = "object"
        s = _render(root, self.title, self.known)
        s.update({"$schema": "https://json-schema.org/draft/2020-12/schema", "title": self.title,
                  "description": self.description})
        return s


def check_foxglove_subset(schema: dict[str, Any], where: str = "<root>") -> list[str]:
    """Violations of the subset Foxglove/Lichtblick parse (empty list = parseable)."""
    errs = []
    if schema.get("type") != "object" or not isinstance(schema.get("properties"), dict):
        return [f"{where}: expected an object schema with properties"]
    for key, sub in schema["properties"].items():
        t, path = sub.get("type"), f"{where}.{key}"
        if t == "object":
            errs += check_foxglove_subset(sub, path)
        elif t == "array":
            it = sub.get("items") or {}
            if it.get("type") == "object":
                errs += check_foxglove_subset(it, path + "[]")
            elif it.get("type") not in ("number", "integer", "boolean", "string"):
                errs.append(f"{path}: array items of type {it.get('type')!r}")
        elif t not in ("number", "integer", "boolean", "string"):
            errs.append(f"{path}: type {t!r}")
    return errs


# ---------------------------------------------------------------- Foxglove well-known schemas
_TIME = {"type": "object", "title": "time", "description": "timestamp: MCAP log time (bus time)",
         "properties": {"sec": {"type": "integer", "minimum": 0, "description": "seconds"},
                        "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999,
                                 "description": "nanoseconds"}}}


def _xyz(names: str, title: str, desc: str) -> dict[str, Any]:
    return {"type": "object", "title": title, "description": desc,
            "properties": {c: {"type": "number", "description": f"{c} component"} for c in names},
            "required": list(names)}


FRAME_TRANSFORM: dict[str, Any] = {
    "title": "foxglove.FrameTransform",
    "description": "transform between two frames: rotation maps child-frame components to "
                   "parent-frame components (the child's orientation in the parent)",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "parent_frame_id": {"type": "string", "description": "parent frame name"},
        "child_frame_id": {"type": "string", "description": "child frame name"},
        "translation": _xyz("xyz", "foxglove.Vector3",
                            "child origin in the parent frame (m); zero: co-located frames"),
        "rotation": _xyz("xyzw", "foxglove.Quaternion",
                         "q_parent_from_child, scalar-last (dimensionless)"),
    },
    "required": ["timestamp", "parent_frame_id", "child_frame_id", "translation", "rotation"],
}

LOG_LEVELS = {"DEBUG": 1, "INFO": 2, "WARNING": 3, "ERROR": 4, "FATAL": 5}

LOG: dict[str, Any] = {
    "title": "foxglove.Log",
    "description": "a log message (here: fault-flag changes of the filter)",
    "type": "object",
    "properties": {
        "timestamp": _TIME,
        "level": {"type": "integer", "description": "log level: 1 DEBUG, 2 INFO, 3 WARNING, "
                  "4 ERROR, 5 FATAL"},
        "message": {"type": "string", "description": "text"},
        "name": {"type": "string", "description": "source name"},
        "file": {"type": "string", "description": "file name (empty)"},
        "line": {"type": "integer", "minimum": 0, "description": "line number (0)"},
    },
    "required": ["timestamp", "level", "message", "name", "file", "line"],
}


def paper_schema() -> dict[str, Any]:
    """Schema of ``/paper/calibration``: estimates, 1σ and truth in the paper's units."""
    from monitors.common import PAPER_UNITS

    def group_map(what: str) -> dict[str, Any]:
        return {"type": "object", "description": f"{what}, paper units",
                "properties": {g: {"type": "array", "items": {"type": "number"},
                                   "description": f"{what} of {g} ({u}), one per gyro (phi2: "
                                                  "body axes x, y, z)"}
                               for g, u in PAPER_UNITS.items()}}

    return {"$schema": "https://json-schema.org/draft/2020-12/schema",
            "title": "radical.paper.calibration", "type": "object",
            "description": "calibration in the paper's units (b deg/hr, lam and mu ppm, du, dv "
                           "and phi2 arcsec), from each /tlm/large (or /tlm/medium) packet",
            "properties": {
                "t": {"type": "number", "description": "time of the estimate, bus time (s)"},
                "est": group_map("estimate"), "sigma": group_map("1-sigma"),
                "truth": group_map("simulator truth (simulated archives)"),
                "err_over_sigma": group_map("(estimate - truth) / sigma (dimensionless; the "
                                            "units listed are those of the estimate)"),
                "att_sigma_arcsec": {"type": "array", "items": {"type": "number"},
                                     "description": "attitude 1-sigma, body x, y, z (arcsec)"},
            }}


def known_schema(topic: str) -> dict[str, Any] | None:
    """The contract schema of a topic (deep copy), or None."""
    from radical_rt.contract.schemas import SCHEMAS  # the contract schemas the archive layer writes

    s = SCHEMAS.get(topic)
    return copy.deepcopy(s) if s is not None else None
