"""JSON Schemas (draft 2020-12) of the RADICAL-RT messages (CONTRACT.md §3, §4), one per MCAP topic.

Each schema is stored in the archive next to its channel (schema encoding ``jsonschema``, name
``radical.<topic>``, e.g. ``radical.siru``, ``radical.tlm.small``); payloads themselves are
msgpack maps. Every field's ``description`` states its unit. Units are SI (rad, rad/s, s), except
the temperatures, which are in degrees Celsius as their ``_C`` names say.

Extensions are compatible by contract (new optional fields): every schema allows additional
properties, so a reader keeps ignoring fields it does not know. ``validate`` also checks what JSON
Schema cannot express: the columns of a columnar message (``/siru``, ``/truth/siru_time``) have the
same length k, and the ``dtheta`` rows all have the same length n.

Only stdlib, numpy and jsonschema are imported (a leaf module: the archive layer
:mod:`radical_rt.io.archive`, the recorder and the Foxglove export use it).
"""

from __future__ import annotations

from functools import cache
from typing import Any

import numpy as np

__all__ = ["SCHEMAS", "schema_name", "validate", "validator_for"]

_DIALECT = "https://json-schema.org/draft/2020-12/schema"
_MODES = ["init", "converging", "converged", "degraded"]
_FLAG_NAMES = ("PARITY_ALARM, GYRO_A_FAILED, GYRO_B_FAILED, GYRO_C_FAILED, GYRO_D_FAILED, "
               "ST1_EDITED, ST2_EDITED, ST1_STALE, ST2_STALE, GYRO_GAP, CLOCK_ANOMALY, NUMERIC, "
               "INPUT_REJECTED, NOT_CONVERGED (bits 0-13; more from bit 16 up)")


# ----------------------------------------------------------------------------------- fragments
def _num(desc: str) -> dict[str, Any]:
    return {"type": "number", "description": desc}


def _int(desc: str, minimum: int | None = 0, maximum: int | None = None) -> dict[str, Any]:
    s: dict[str, Any] = {"type": "integer", "description": desc}
    if minimum is not None:
        s["minimum"] = minimum
    if maximum is not None:
        s["maximum"] = maximum
    return s


def _vec(n: int, desc: str, *, at_least: bool = False, nonneg: bool = False) -> dict[str, Any]:
    """Array of exactly ``n`` numbers (or at least ``n`` with ``at_least``)."""
    item: dict[str, Any] = {"type": "number"}
    if nonneg:
        item["minimum"] = 0
    s: dict[str, Any] = {"type": "array", "description": desc, "items": item, "minItems": n}
    if not at_least:
        s["maxItems"] = n
    return s


def _quat(desc: str) -> dict[str, Any]:
    return _vec(4, desc + "; quaternion scalar-last [x, y, z, w], unit norm (dimensionless)")


def _column(item: dict[str, Any], desc: str) -> dict[str, Any]:
    """One column of a columnar batch: k >= 1 entries."""
    return {"type": "array", "description": desc, "items": item, "minItems": 1}


_V = {"const": 1, "description": "message format version (dimensionless); always 1"}
_T_BUS = _num("bus time t_bus of the sample (s, spacecraft bus clock)")
_T_EST = _num("time of the estimate on the bus time line (s)")
_TT_ITEM = {"type": "integer", "minimum": 0, "maximum": (1 << 32) - 1}

_PARAM_DOC = {
    "b": "gyro biases (rad/s), one per gyro (n >= 4)",
    "lam": "symmetric scale factors (dimensionless, 1 = 1e6 ppm), one per gyro (n >= 4)",
    "mu": "asymmetric scale factors (dimensionless), one per gyro (n >= 4)",
    "du": "sense-axis misalignments along v_i (rad), one per gyro (n >= 4)",
    "dv": "sense-axis misalignments along u_i (rad), one per gyro (n >= 4)",
    "phi2": "ST2 misalignment rotation vector (rad, body axes), 3 components",
}


def _params(prefix: str, *, nonneg: bool = False) -> dict[str, dict[str, Any]]:
    """The §1.5 calibration parameter lists (SI): 4+ per gyro, phi2 exactly 3."""
    out = {k: _vec(4, prefix + d, at_least=True, nonneg=nonneg)
           for k, d in _PARAM_DOC.items() if k != "phi2"}
    out["phi2"] = _vec(3, prefix + _PARAM_DOC["phi2"], nonneg=nonneg)
    return out


def _params_map(desc: str, prefix: str, *, nonneg: bool = False) -> dict[str, Any]:
    return {"type": "object", "description": desc, "properties": _params(prefix, nonneg=nonneg),
            "required": list(_PARAM_DOC), "additionalProperties": True}


def _obj(name: str, desc: str, props: dict[str, Any], required: list[str]) -> dict[str, Any]:
    return {"$schema": _DIALECT, "title": name, "description": desc, "type": "object",
            "properties": {"v": _V, **props}, "required": ["v", *required],
            "additionalProperties": True}


# ------------------------------------------------------------------------------------- schemas
def schema_name(topic: str) -> str:
    """MCAP schema name of a topic: ``/tlm/small`` -> ``radical.tlm.small``."""
    return "radical." + topic.lstrip("/").replace("/", ".")


def _build() -> dict[str, dict[str, Any]]:
    s: dict[str, dict[str, Any]] = {}

    def add(topic: str, desc: str, props: dict[str, Any], required: list[str]) -> None:
        s[topic] = _obj(schema_name(topic), desc, props, required)

    # ---- inputs
    add("/siru", "SIRU read batch, columnar: k >= 1 samples in read order (all columns length k)", {
        "t_bus": _column({"type": "number"}, "bus time of each read (s), [k]"),
        "tt": _column(_TT_ITEM, "SIRU time-tag counter of each sample (ticks of 1 us nominal "
                                "on the SIRU oscillator, wraps at 2^32), [k]"),
        "dtheta": _column(_vec(4, "one sample", at_least=True),
                          "integrated angle increment per gyro A, B, C, D, ... (rad), [k][n], n >= 4"),
        "status": _column({"type": "integer", "minimum": 0},
                          "validity bits per sample (bit i set = gyro i invalid; 0 = all valid), [k]"),
    }, ["t_bus", "tt", "dtheta", "status"])
    for j in (1, 2):
        add(f"/st{j}", f"star tracker ST{j} attitude sample", {
            "t_bus": _T_BUS,
            "q": _quat(f"q_st{j}_from_inertial: tracker frame from J2000 inertial"),
            "n_stars": _int("number of stars used (count)"),
            "valid": {"type": "boolean", "description": "tracker reports the solution valid"},
        }, ["t_bus", "q", "n_stars", "valid"])
    add("/temp", "temperatures (any sensor may be missing)", {
        "t_bus": _T_BUS,
        "st1_baseplate_C": _num("ST1 baseplate temperature (degrees Celsius)"),
        "st2_baseplate_C": _num("ST2 baseplate temperature (degrees Celsius)"),
        "siru_C": _num("SIRU temperature (degrees Celsius)"),
    }, ["t_bus"])

    # ---- outputs (packets are configurable: only the tlm/small defaults are required)
    small = {
        "seq": _int("packet sequence number (count)"),
        "t": _T_EST,
        "q_body_from_inertial": _quat("estimated attitude q_body_from_inertial"),
        "flags": _int("fault flag bits (CONTRACT §3.1): " + _FLAG_NAMES),
        "mode": {"enum": _MODES, "description": "filter mode"},
    }
    small_req = list(small)
    medium = {
        **small,
        "omega_body": _vec(3, "estimated body angular rate (rad/s, body axes)"),
        "est": _params_map("estimated calibration parameters (SI)", "estimate: "),
    }
    large = {
        **medium,
        "sigma": _params_map("1-sigma uncertainty of the estimates (SI, same units as est)",
                             "1-sigma of ", nonneg=True),
        "att_sigma": _vec(3, "1-sigma attitude uncertainty (rad, body axes)", nonneg=True),
        "counters": {"type": "object", "description": "event counters (counts), e.g. "
                     "siru_samples, siru_repeated, siru_missing, st1_used, st1_edited, "
                     "st2_used, st2_edited, input_rejected"},
    }
    add("/tlm/small", "small telemetry packet (defaults; more fields may be configured)",
        small, small_req)
    add("/tlm/medium", "medium telemetry packet: small + omega_body + est (defaults)",
        medium, small_req)
    add("/tlm/large", "large telemetry packet: medium + sigma + att_sigma + residual statistics "
        "+ clock estimates + counters (defaults)", large, small_req)
    names = {"type": "array", "items": {"type": "string"}}
    add("/fault", "fault flags change, published on every change of flags", {
        "t": _T_EST,
        "flags": _int("fault flag bits after the change (CONTRACT §3.1): " + _FLAG_NAMES),
        "set": {**names, "description": "names of the flags that were set by this change"},
        "cleared": {**names, "description": "names of the flags cleared by this change"},
        "detail": {"type": "object", "description": "free-form details per flag (SI units)"},
    }, ["t", "flags", "set", "cleared", "detail"])
    add("/diag", "free-form diagnostics (innovations, NIS, edit decisions, UD health, clock fit; "
        "SI units)", {"t": _T_EST}, [])

    text = {"type": ["string", "null"]}
    add("/cmd_log", "audit record of one command received by the node, applied or refused "
        "(extension, docs/security.md)", {
            "t_wall": _num("wall-clock time the node answered (Unix s)"),
            "vehicle": {"type": "string", "description": "vehicle the command was for"},
            "user": {"type": "string", "description": "sender: the user of the command key, "
                     "or 'anonymous' on the contract key"},
            "role": {**text, "description": "the user's role in the node's profile (null: none)"},
            "authenticated": {"type": "boolean", "description": "the user was checked by the "
                              "node's security profile (false: claimed or unknown)"},
            "key": {"type": "string", "description": "contract, read or write"},
            "cmd": {**text, "description": "command name (null: unreadable request)"},
            "args": {"type": ["object", "null"], "description": "arguments as sent"},
            "ok": {"type": "boolean", "description": "applied (true) or refused"},
            "error": {**text, "description": "why it was refused"},
        }, ["t_wall", "vehicle", "user", "key", "ok"])

    # ---- truth (simulated archives only; ignored by the filter)
    add("/truth/attitude", "true attitude and rate (>= 10 Hz)", {
        "t_bus": _T_BUS,
        "q_body_from_inertial": _quat("true attitude q_body_from_inertial"),
        "omega_body": _vec(3, "true body angular rate (rad/s, body axes)"),
    }, ["t_bus", "q_body_from_inertial", "omega_body"])
    add("/truth/params", "true sensor parameters of CONTRACT §1.5 in SI (>= 1 Hz)",
        {"t_bus": _T_BUS, **_params("true ")}, ["t_bus", *_PARAM_DOC])
    add("/truth/siru_time", "true bus time of SIRU samples, columnar (all columns length k)", {
        "tt": _column(_TT_ITEM, "SIRU time-tag counter of each sample (ticks, wraps at 2^32), [k]"),
        "t_true": _column({"type": "number"},
                          "true bus time at which each SIRU sample was taken (s), [k]"),
        "t_bus": _num("bus time at which this truth record was written (s), optional"),
    }, ["tt", "t_true"])
    return s


SCHEMAS: dict[str, dict[str, Any]] = _build()
_COLUMNS = {"/siru": ("t_bus", "tt", "dtheta", "status"), "/truth/siru_time": ("tt", "t_true")}


# ----------------------------------------------------------------------------------- validation
def _is_array(_checker: Any, inst: Any) -> bool:
    return isinstance(inst, list | tuple | np.ndarray)


def _is_number(_checker: Any, inst: Any) -> bool:
    return isinstance(inst, int | float | np.integer | np.floating) and not isinstance(
        inst, bool | np.bool_)


def _is_integer(checker: Any, inst: Any) -> bool:
    if isinstance(inst, np.integer):
        return True
    if isinstance(inst, np.floating):
        return bool(float(inst).is_integer())
    from jsonschema import Draft202012Validator  # (loaded by then: see _validator_class)

    return Draft202012Validator.TYPE_CHECKER.is_type(inst, "integer")


def _is_boolean(_checker: Any, inst: Any) -> bool:
    return isinstance(inst, bool | np.bool_)


@cache
def _validator_class() -> Any:
    """Draft 2020-12 accepting numpy arrays and scalars as well as the lists/ints/floats msgpack
    decodes to (jsonschema is imported here, at the first validation: the archive layer imports
    this module for SCHEMAS, and `radical process` validates nothing)."""
    from jsonschema import Draft202012Validator, validators

    return validators.extend(
        Draft202012Validator,
        type_checker=Draft202012Validator.TYPE_CHECKER.redefine_many(
            {"array": _is_array, "number": _is_number, "integer": _is_integer,
             "boolean": _is_boolean}))


@cache
def validator_for(topic: str) -> Any:
    """Cached jsonschema validator of a known topic (KeyError for an unknown one)."""
    return _validator_class()(SCHEMAS[topic])


def _column_errors(topic: str, msg: Any) -> list[str]:
    cols = _COLUMNS.get(topic)
    if cols is None or not isinstance(msg, dict):
        return []
    lens = {c: len(msg[c]) for c in cols if _is_array(None, msg.get(c))}
    errs = []
    if len(set(lens.values())) > 1:
        errs.append(f"{topic}: columns differ in length: "
                    + ", ".join(f"{c}[{n}]" for c, n in lens.items()))
    rows: Any = msg.get("dtheta")
    if topic == "/siru" and _is_array(None, rows):
        widths = {len(r) for r in rows if _is_array(None, r)}
        if len(widths) > 1:
            errs.append(f"{topic}: dtheta rows differ in length: {sorted(widths)}")
    return errs


def validate(topic: str, msg: Any) -> list[str]:
    """Errors of ``msg`` against the schema of ``topic`` (MCAP topic, leading slash).

    Returns one line per error, ``"<topic>: <path>: <message>"``; an empty list means valid. An
    unknown topic gives one error.
    """
    if topic not in SCHEMAS:
        return [f"{topic}: unknown topic (no schema; known: {', '.join(SCHEMAS)})"]
    errs = []
    for e in sorted(validator_for(topic).iter_errors(msg), key=lambda e: [str(p) for p in e.absolute_path]):
        where = "/".join(str(p) for p in e.absolute_path) or "<root>"
        errs.append(f"{topic}: {where}: {e.message}")
    return errs + _column_errors(topic, msg)
