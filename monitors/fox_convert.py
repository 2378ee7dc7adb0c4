"""Contract messages → JSON messages for Foxglove / Lichtblick (shared by export and live server).

:class:`FoxgloveConverter` takes each contract message (CONTRACT §3, §4: a decoded msgpack map,
SI units) with its topic and MCAP log time and returns the JSON messages to publish:

* the message itself on the same topic, JSON-ready (:func:`jsonable`): map keys as strings,
  ``None`` and non-finite numbers left out of maps (JSON has no NaN; a missing field plots as a
  gap), ``/siru``'s ``dtheta`` [k][n] turned into one column per gyro ``{"A": [k], "B": [k], …}``
  (Foxglove's JSON Schema datatypes have no arrays of arrays);
* ``foxglove.FrameTransform`` messages: ``/tf/body`` (inertial → body, estimated, from
  ``/tlm/small``, else ``/tlm/medium`` or ``/tlm/large``), ``/tf/body_truth`` (inertial →
  body_truth, from ``/truth/attitude``), ``/tf/st1`` (body → st1, the contract's fixed mounting)
  and ``/tf/st2`` (body → st2 with the estimated misalignment phi2), both at each packet that
  carries ``est``, and ``/tf/st2_truth`` (body → st2_truth, the true phi2 of each
  ``/truth/params``: next to st2 it shows the misalignment error); rotations are ``q_parent_from_child`` (Foxglove: the child's orientation in the
  parent), translations zero (the frames share an origin);
* ``foxglove.Log`` on ``/log/faults`` for every ``/fault`` message (flags set and cleared, by
  name; level ERROR for failures, WARNING for edits/staleness/gaps, INFO otherwise);
* ``/paper/calibration``: estimates, 1σ, truth and error/σ in the paper's units (deg/hr, ppm,
  arcsec) from each ``/tlm/large`` (else ``/tlm/medium``) packet.

Timestamps are the MCAP log time (bus time, ns).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from monitors.common import ORDER, group_paper
from monitors.fox_schema import FRAME_TRANSFORM, LOG, LOG_LEVELS, paper_schema
from radical_rt.contract.conventions import ARCSEC
from radical_rt.contract.flags import Flag

#: Nominal tracker mountings (CONTRACT §1.4).
R_ST1_FROM_BODY = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])
R_ST2_FROM_BODY_NOM = np.array([[0, -1.0, 0], [-1.0, 0, 0], [0, 0, -1.0]])
GYRO_NAMES = "ABCDEFGHIJKLMNOPQRSTUVWXYZ"

TF_TOPICS = {"/tf/body": ("inertial", "body"), "/tf/body_truth": ("inertial", "body_truth"),
             "/tf/st1": ("body", "st1"), "/tf/st2": ("body", "st2"),
             "/tf/st2_truth": ("body", "st2_truth")}
LOG_TOPIC = "/log/faults"
PAPER_TOPIC = "/paper/calibration"
#: derived topic -> (schema name, schema) for the channels made here
DERIVED_SCHEMAS: dict[str, tuple[str, dict[str, Any]]] = {
    **{t: ("foxglove.FrameTransform", FRAME_TRANSFORM) for t in TF_TOPICS},
    LOG_TOPIC: ("foxglove.Log", LOG),
    PAPER_TOPIC: ("radical.paper.calibration", paper_schema()),
}

_RANK = {"/tlm/small": 0, "/tlm/medium": 1, "/tlm/large": 2}  # attitude source preference
_ERROR_FLAGS = (Flag.PARITY_ALARM | Flag.GYRO_A_FAILED | Flag.GYRO_B_FAILED | Flag.GYRO_C_FAILED
                | Flag.GYRO_D_FAILED | Flag.NUMERIC)
_WARN_FLAGS = (Flag.ST1_EDITED | Flag.ST2_EDITED | Flag.ST1_STALE | Flag.ST2_STALE
               | Flag.GYRO_GAP | Flag.CLOCK_ANOMALY | Flag.INPUT_REJECTED)


def jsonable(v: Any) -> Any:
    """A JSON-ready version: str keys, None/NaN/inf dropped from maps (null inside lists), numpy
    values as Python numbers, bytes as hex strings. Lists of finite floats are returned as they
    are (the messages are freshly decoded and never mutated)."""
    t = type(v)
    if t is float:
        return v if v - v == 0.0 else None  # NaN - NaN and inf - inf are NaN
    if t is int or t is str or t is bool:
        return v
    if t is dict:
        out = {}
        for k, x in v.items():
            y = jsonable(x)
            if y is not None:
                out[k if type(k) is str else str(k)] = y
        return out
    if t is list:
        if all(type(x) is float and x - x == 0.0 for x in v):
            return v
        return [jsonable(x) for x in v]
    if isinstance(v, tuple):
        return [jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return jsonable(v.tolist())
    if isinstance(v, np.generic):
        return jsonable(v.item())
    if isinstance(v, bytes | bytearray):
        return bytes(v).hex()
    if isinstance(v, bool | int | str):
        return v
    if isinstance(v, float):
        return v if math.isfinite(v) else None
    return None if v is None else str(v)


def siru_columns(msg: dict[str, Any]) -> dict[str, Any]:
    """``/siru`` with ``dtheta`` [k][n] (rad) as per-gyro columns ``{"A": [k], …}``."""
    out = dict(msg)
    rows = msg.get("dtheta")
    if isinstance(rows, list) and rows and all(isinstance(r, list) for r in rows):
        n = max(len(r) for r in rows)
        out["dtheta"] = {GYRO_NAMES[i] if i < 26 else f"G{i}":
                         [r[i] if i < len(r) else None for r in rows] for i in range(n)}
    return out


def siru_known_schema(known: dict[str, Any] | None) -> dict[str, Any] | None:
    """The contract's /siru schema with ``dtheta`` described as the per-gyro columns."""
    if known is None:
        return None
    props = known.setdefault("properties", {})
    props["dtheta"] = {"type": "object", "description": "integrated angle increment of each gyro "
                       "(rad), one column [k] per gyro A, B, C, D, ... (read order)",
                       "properties": {}}
    return known


def stamp(log_time_ns: int) -> dict[str, int]:
    """Foxglove time {sec, nsec} of a log time (ns, ≥ 0)."""
    ns = max(int(log_time_ns), 0)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def frame_transform(log_time_ns: int, parent: str, child: str,
                    q_parent_from_child: Any) -> dict[str, Any]:
    """A foxglove.FrameTransform message (rotation scalar-last, normalised; translation zero)."""
    q = np.asarray(q_parent_from_child, dtype=float)
    q = q / np.linalg.norm(q)
    return {"timestamp": stamp(log_time_ns), "parent_frame_id": parent, "child_frame_id": child,
            "translation": {"x": 0.0, "y": 0.0, "z": 0.0},
            "rotation": {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])}}


def _quat(v: Any) -> np.ndarray | None:
    try:
        q = np.asarray(v, dtype=float).reshape(4)
    except (TypeError, ValueError):
        return None
    n = np.linalg.norm(q)
    return q / n if np.isfinite(n) and n > 0 else None


def inverse_quat(q: np.ndarray) -> np.ndarray:
    """Conjugate of a unit quaternion (scalar-last): q_Y_from_X from q_X_from_Y."""
    return np.array([-q[0], -q[1], -q[2], q[3]])


Q_BODY_FROM_ST1 = Rotation.from_matrix(R_ST1_FROM_BODY.T).as_quat()


def q_body_from_st2(phi2: Any) -> np.ndarray | None:
    """q_body_from_st2 for the ST2 misalignment phi2 (rad, body axes):
    R_st2_from_body = R_st2_from_body_nom @ R(phi2).T (CONTRACT §1.4)."""
    try:
        p = np.asarray(phi2, dtype=float).reshape(3)
    except (TypeError, ValueError):
        return None
    if not np.all(np.isfinite(p)):
        return None
    r = R_ST2_FROM_BODY_NOM @ Rotation.from_rotvec(p).as_matrix().T
    return Rotation.from_matrix(r.T).as_quat()


def fault_log(log_time_ns: int, msg: dict[str, Any]) -> dict[str, Any]:
    """A foxglove.Log message for one ``/fault`` message."""
    set_, cleared = list(msg.get("set") or []), list(msg.get("cleared") or [])
    bits = 0
    for name in set_:
        bits |= int(Flag[name]) if name in Flag.__members__ else 0
    level = ("ERROR" if bits & _ERROR_FLAGS else "WARNING" if bits & _WARN_FLAGS else "INFO")
    flags = msg.get("flags")
    text = (f"set: {', '.join(map(str, set_)) or '-'}; cleared: "
            f"{', '.join(map(str, cleared)) or '-'}; flags=0x{int(flags or 0):04x}")
    mode = (msg.get("detail") or {}).get("mode") if isinstance(msg.get("detail"), dict) else None
    if mode:
        text += f"; mode {mode}"
    return {"timestamp": stamp(log_time_ns), "level": LOG_LEVELS[level], "message": text,
            "name": "radical.fault", "file": "", "line": 0}


class FoxgloveConverter:
    """Stateful converter of one stream (see module doc). ``att_topic``: the telemetry topic
    whose attitude drives ``/tf/body`` (None: the fastest of /tlm/small, medium, large seen so
    far); ``cal_topic``: the one that drives the calibration channels (None: large, else
    medium)."""

    def __init__(self, att_topic: str | None = None, cal_topic: str | None = None) -> None:
        self.att_topic, self.cal_topic = att_topic, cal_topic
        self._truth: dict[str, Any] | None = None

    def convert(self, topic: str, log_time_ns: int, msg: Any) -> list[tuple[str, dict[str, Any]]]:
        """[(topic, json message), …] for one decoded contract message."""
        if not isinstance(msg, dict):
            return []
        body = siru_columns(msg) if topic == "/siru" else msg
        out: list[tuple[str, dict[str, Any]]] = [(topic, jsonable(body))]
        if topic.startswith("/tlm/"):
            out += self._tlm(topic, log_time_ns, msg)
        elif topic == "/truth/attitude":
            q = _quat(msg.get("q_body_from_inertial"))
            if q is not None:
                out.append(("/tf/body_truth", frame_transform(log_time_ns, "inertial",
                                                              "body_truth", inverse_quat(q))))
        elif topic == "/truth/params":
            self._truth = msg
            q2 = q_body_from_st2(msg.get("phi2"))
            if q2 is not None:
                out.append(("/tf/st2_truth", frame_transform(log_time_ns, "body", "st2_truth",
                                                             q2)))
        elif topic == "/fault":
            out.append((LOG_TOPIC, fault_log(log_time_ns, msg)))
        return out

    def _tlm(self, topic: str, ns: int, msg: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
        out = []
        current = _RANK.get(self.att_topic, 10) if self.att_topic is not None else 10
        if "q_body_from_inertial" in msg and _RANK.get(topic, 9) < current:
            self.att_topic = topic  # live: the fastest packet seen so far drives /tf/body
        if topic == self.att_topic:
            q = _quat(msg.get("q_body_from_inertial"))
            if q is not None:
                out.append(("/tf/body", frame_transform(ns, "inertial", "body", inverse_quat(q))))
        est = msg.get("est")
        if not isinstance(est, dict):
            return out
        if self.cal_topic is None or (self.cal_topic == "/tlm/medium" and topic == "/tlm/large"):
            self.cal_topic = topic
        if topic != self.cal_topic:
            return out
        out.append(("/tf/st1", frame_transform(ns, "body", "st1", Q_BODY_FROM_ST1)))
        q2 = q_body_from_st2(est.get("phi2"))
        if q2 is not None:
            out.append(("/tf/st2", frame_transform(ns, "body", "st2", q2)))
        out.append((PAPER_TOPIC, self.paper(msg)))
        return out

    def paper(self, msg: dict[str, Any]) -> dict[str, Any]:
        """The paper-units message of a packet with ``est`` (and ``sigma``, truth when known)."""
        est, sig = msg.get("est") or {}, msg.get("sigma") or {}
        out: dict[str, Any] = {"t": msg.get("t"), "est": {}, "sigma": {}}
        truth = self._truth
        if truth is not None:
            out["truth"], out["err_over_sigma"] = {}, {}
        for g in ORDER:
            if not isinstance(est.get(g), list):
                continue
            e = group_paper(g, est[g])
            out["est"][g] = e
            s = group_paper(g, sig[g]) if isinstance(sig.get(g), list) else None
            if s is not None:
                out["sigma"][g] = s
            if truth is not None and isinstance(truth.get(g), list):
                tr = group_paper(g, truth[g])
                out["truth"][g] = tr
                if s is not None:
                    out["err_over_sigma"][g] = [(a - b) / c if c else math.nan
                                                for a, b, c in zip(e, tr, s, strict=False)]
        att = msg.get("att_sigma")
        if isinstance(att, list):
            out["att_sigma_arcsec"] = [float(a) / ARCSEC for a in att]
        return jsonable(out)
