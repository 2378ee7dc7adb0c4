"""Scenario key specification (names carry units), defaults, validation and TOML printing.

A scenario is a nested mapping: top-level keys plus the tables ``[maneuver]``, ``[truth]``,
``[siru]``, ``[trackers]``, ``[thermal]``, ``[output]`` and the array of tables ``[[faults]]``.
Keys whose default is ``None`` are optional overrides (resolved from the profile or the truth
source). Every key is documented in docs/scenarios.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

N_GYRO = 4


class ScenarioError(ValueError):
    """A scenario is invalid. The message names the offending key."""


@dataclass(frozen=True)
class F:
    """One key: type tag, default value (None = optional override) and a one-line doc with units.

    Type tags: 'str', 'int', 'float', 'bool', 'float[K]' (K floats), 'float[]' (any length),
    'moves' (array of move tables), 'faults' (array of fault tables).
    """

    kind: str
    default: Any
    doc: str


SPEC: dict[str, Any] = {
    "name": F("str", "2006216", "scenario name (archive metadata)"),
    "base": F("str", None, "built-in scenario this file inherits (TOML files only)"),
    "vehicle": F("str", "messenger", "vehicle name, [a-z0-9_-]+"),
    "seed": F("int", 2006216, "seed of every random stream"),
    "duration_s": F("float", 7200.0, "run length, s"),
    "t_start_s": F("float", 0.0, "bus time of the run start, s"),
    "maneuver": {
        "profile": F("str", "messenger", "built-in profile: messenger | original | alternate | none"),
        "rate_deg_s": F("float", 0.3, "maximum slew rate, deg/s"),
        "ramp_s": F("float", 20.0, "rate ramp time (trapezoid), s"),
        "start_s": F("float", None, "hold before the first move, s (default: the profile's)"),
        "q0_body_from_inertial": F("float[4]", [0.1, -0.3, 0.4, 0.8602325267042626],
                                   "initial attitude, scalar-last (normalized on load)"),
        "moves": F("moves", None, "explicit moves {axis, angle_deg, hold_s} (default: the profile's)"),
    },
    "truth": {
        "source": F("str", "2006216",
                    "truth parameters: a table row (2005300 | 2005301 | 2006216 | "
                    "2005301-2006216), 'uniform' (Table 1, [-L, L]) or 'zero'"),
        "uniform_fraction": F("float", 1.0, "for source='uniform': draw on [-f·L, f·L]"),
        "b_deg_hr": F(f"float[{N_GYRO}]", None, "gyro biases, deg/hr (overrides the source)"),
        "lam_ppm": F(f"float[{N_GYRO}]", None, "symmetric scale factors, ppm"),
        "mu_ppm": F(f"float[{N_GYRO}]", None, "asymmetric scale factors, ppm"),
        "du_arcsec": F(f"float[{N_GYRO}]", None, "misalignments along v_i, arcsec"),
        "dv_arcsec": F(f"float[{N_GYRO}]", None, "misalignments along u_i, arcsec"),
        "phi2_arcsec": F("float[3]", None, "ST2 misalignment at T2(0), body axes, arcsec"),
    },
    "siru": {
        "period_s": F("float", 0.01, "nominal SIRU sample period, s"),
        "eps_ppm": F("float", 40.0, "SIRU oscillator offset: true period = period·(1+eps), ppm"),
        "phase_s": F("float", 0.0043, "time of SIRU sample 0 after the run start, s, [0, period)"),
        "sample_jitter_s": F("float", 1e-6, "SIRU sample-time jitter, 1σ, s (truncated at 4σ)"),
        "bus_period_s": F("float", 0.01, "bus read period, s"),
        "read_jitter_s": F("float", 2e-5, "bus read-time jitter, 1σ, s (truncated at 4σ)"),
        "tt0": F("int", 0, "time-tag counter of sample 0, [0, 2**32)"),
        "tt_reset_s": F("float[]", [], "times (s from run start) of time-tag counter resets"),
        "arw_deg_sqrt_hr": F("float", 1.5e-4, "angle random walk, deg/√hr"),
        "bias_rw_rad_s_sqrt_s": F("float", 1e-11, "bias random walk, rad/s/√s"),
        "bias_instability_deg_hr": F("float", 0.0, "bias instability B (flicker bias, IEEE Std 952: "
                                     "Allan floor 0.664·B), deg/hr (0 = none)"),
        "quantum_arcsec": F("float", 0.01, "quantum of the accumulated angle, arcsec (0 = none)"),
        "batch": F("int", 10, "bus reads per /siru message"),
        # Bus-read timing (optional; absent = the defaults in TIMING_DEFAULTS, so that archives of
        # scenarios without them stay byte-identical). docs/scenarios.md, "Bus-read timing".
        "tag_mode": F("str", None, "read tag: 'read' (t_bus = read instant) or 'tick' "
                                   "(t_bus = nominal bus tick, the read before it); default read"),
        "read_offset_s": F("float", None, "tick mode: the read precedes its tick by this, s, "
                                          "[0, bus_period/5]; default 0"),
        "read_jitter_dist": F("str", None, "read jitter distribution: gaussian (±4σ) | uniform "
                                           "| student_t (±min(20σ, bus_period/5)); default gaussian"),
        "read_jitter_dof": F("float", None, "student_t degrees of freedom (> 2); default 3"),
        "late_read_prob": F("float", None, "probability per read of a late read, [0, 1]; default 0"),
        "late_read_max_s": F("float", None, "a late read is delayed by U(0, this), s, "
                                            "[0, bus_period/4]; default 0"),
    },
    "trackers": {
        "st1": F("bool", True, "ST1 on"),
        "st2": F("bool", True, "ST2 on"),
        "rate_hz": F("float", 10.0, "tracker output rate, Hz (divides the bus rate)"),
        "latency_s": F("float", 0.115, "tracker latency: reports the attitude at t_bus − latency, s"),
        "sigma_xy_arcsec": F("float", 3.2, "cross-boresight noise 1σ at n_stars_ref stars, arcsec"),
        "sigma_z_arcsec": F("float", 29.0, "boresight noise 1σ at n_stars_ref stars, arcsec"),
        "n_stars_ref": F("int", 9, "star count of the quoted noise"),
        "n_stars_min": F("int", 5, "star count, lower bound"),
        "n_stars_max": F("int", 12, "star count, upper bound"),
        "n_stars_start": F("int", 9, "star count at the start"),
        "n_stars_step_prob": F("float", 0.005, "probability per sample of a ±1 star-count step"),
        "invalid_prob": F("float", 0.005, "probability per sample of valid=false (corrupted q)"),
        "invalid_error_deg": F("float", 5.0, "max error of an invalid sample's q, deg"),
        "dropout_prob": F("float", 0.002, "probability per sample of a missing sample"),
    },
    "thermal": {
        "rate_hz": F("float", 1.0, "/temp rate, Hz"),
        "tau_s": F("float", 3600.0, "time constant of the first-order temperature rise, s"),
        "st1_C0": F("float", 20.0, "ST1 baseplate temperature at the start, °C"),
        "st2_C0": F("float", 20.0, "ST2 baseplate temperature at the start, °C"),
        "siru_C0": F("float", 25.0, "SIRU temperature at the start, °C"),
        "st1_rise_C": F("float", 11.6, "ST1 asymptotic rise, °C (both trackers on)"),
        "st2_rise_C": F("float", 11.6, "ST2 asymptotic rise, °C"),
        "siru_rise_C": F("float", 1.0, "SIRU asymptotic rise, °C"),
        "k_temp_arcsec_per_C": F("float[3]", [0.03, 0.015, 0.01],
                                 "d(phi2)/d(T2), body axes, arcsec/°C"),
        "sensor_noise_C": F("float", 0.02, "temperature sensor noise 1σ, °C"),
    },
    "output": {
        "truth": F("bool", True, "write the /truth/* channels"),
        "attitude_hz": F("float", 10.0, "/truth/attitude rate, Hz"),
        "params_hz": F("float", 1.0, "/truth/params rate, Hz"),
        "split_at_gaps": F("bool", False, "write each part between data gaps as its own archive"),
        "chunk_s": F("float", 60.0, "processing chunk, s (bounds memory; output does not depend on it)"),
    },
    "faults": F("faults", [], "fault injections (see FAULT_KEYS)"),
}

#: Values of the optional [siru] bus-read timing keys when a scenario does not set them.
TIMING_DEFAULTS: dict[str, Any] = {"tag_mode": "read", "read_offset_s": 0.0,
                                   "read_jitter_dist": "gaussian", "read_jitter_dof": 3.0,
                                   "late_read_prob": 0.0, "late_read_max_s": 0.0}
TAG_MODES = ("read", "tick")
JITTER_DISTS = ("gaussian", "uniform", "student_t")


def siru_timing(siru: dict) -> dict[str, Any]:
    """The bus-read timing keys of a [siru] table, with TIMING_DEFAULTS for those not set."""
    return {k: siru.get(k, v) for k, v in TIMING_DEFAULTS.items()}


MOVE_KEYS = {"axis": "str", "angle_deg": "float", "hold_s": "float"}

_GYRO_FAULT = {"gyro": "int", "start_s": "float", "end_s": "float"}
#: kind -> (required keys, optional keys), each key -> type tag.
FAULT_KEYS: dict[str, tuple[dict[str, str], dict[str, str]]] = {
    "bias_step": ({"gyro": "int", "start_s": "float", "bias_deg_hr": "float"}, {"end_s": "float"}),
    "bias_ramp": ({"gyro": "int", "start_s": "float", "rate_deg_hr_per_hr": "float"},
                  {"end_s": "float"}),
    "scale_jump": ({"gyro": "int", "start_s": "float", "lam_ppm": "float"}, {"end_s": "float"}),
    "stuck": ({"gyro": "int", "start_s": "float"}, {"end_s": "float"}),
    "zero": ({"gyro": "int", "start_s": "float"}, {"end_s": "float"}),
    "noise_burst": ({"gyro": "int", "start_s": "float", "sigma_arcsec": "float"},
                    {"end_s": "float"}),
    "invalid_status": ({"gyro": "int", "start_s": "float"}, {"end_s": "float"}),
    "tracker_outage": ({"tracker": "str", "start_s": "float", "end_s": "float"}, {}),
    "gap": ({"start_s": "float", "end_s": "float"}, {}),
}


def defaults(spec: dict | None = None) -> dict:
    """The default scenario as a nested dict (optional keys omitted)."""
    spec = SPEC if spec is None else spec
    out: dict[str, Any] = {}
    for key, f in spec.items():
        if isinstance(f, dict):
            out[key] = defaults(f)
        elif f.default is not None:
            out[key] = _copy(f.default)
    return out


def _copy(v):
    return [_copy(x) for x in v] if isinstance(v, list) else dict(v) if isinstance(v, dict) else v


def check_value(path: str, kind: str, v: Any) -> Any:
    """Check one value against its type tag; return it normalized (ints → floats). Raises ScenarioError."""
    if kind == "str" and isinstance(v, str):
        return v
    if kind == "bool" and isinstance(v, bool):
        return v
    if kind == "int" and isinstance(v, int) and not isinstance(v, bool):
        return v
    if kind == "float" and _is_num(v):
        if not math.isfinite(v):
            raise ScenarioError(f"scenario key '{path}': must be finite, got {v!r}")
        return float(v)
    if kind.startswith("float["):
        size = kind[6:-1]
        if isinstance(v, list) and all(_is_num(x) and math.isfinite(x) for x in v):
            if size == "" or len(v) == int(size):
                return [float(x) for x in v]
        want = "a list of finite numbers" if size == "" else f"a list of {size} finite numbers"
        raise ScenarioError(f"scenario key '{path}': expected {want}, got {v!r}")
    if kind in ("str", "bool", "int", "float"):
        raise ScenarioError(f"scenario key '{path}': expected {kind}, got {type(v).__name__} {v!r}")
    raise AssertionError(kind)


def _is_num(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _unknown(path: str, key: str, valid) -> ScenarioError:
    where = f"in [{path}]" if path else "at top level"
    full = f"{path}.{key}" if path else key
    return ScenarioError(f"unknown scenario key '{full}' {where}; valid keys: {', '.join(sorted(valid))}")


def check_tree(data: dict, spec: dict | None = None, path: str = "") -> dict:
    """Validate a (partial) scenario mapping against SPEC; return it normalized. Raises ScenarioError."""
    spec = SPEC if spec is None else spec
    out: dict[str, Any] = {}
    for key, v in data.items():
        full = f"{path}.{key}" if path else key
        if key not in spec:
            raise _unknown(path, key, spec)
        f = spec[key]
        if isinstance(f, dict):
            if not isinstance(v, dict):
                raise ScenarioError(f"scenario key '{full}': expected a table [{full}]")
            out[key] = check_tree(v, f, full)
        elif f.kind == "moves":
            out[key] = [_check_table(f"{full}[{i}]", m, MOVE_KEYS, {"hold_s"}) for i, m in
                        enumerate(_table_list(full, v))]
        elif f.kind == "faults":
            out[key] = [check_fault(f"{full}[{i}]", m) for i, m in enumerate(_table_list(full, v))]
        else:
            out[key] = check_value(full, f.kind, v)
    return out


def _table_list(path: str, v) -> list:
    if not isinstance(v, list) or not all(isinstance(m, dict) for m in v):
        raise ScenarioError(f"scenario key '{path}': expected an array of tables [[{path}]]")
    return v


def _check_table(path: str, m: dict, keys: dict[str, str], optional: set[str]) -> dict:
    out = {}
    for k, v in m.items():
        if k not in keys:
            raise _unknown(path, k, keys)
        out[k] = check_value(f"{path}.{k}", keys[k], v)
    missing = [k for k in keys if k not in out and k not in optional]
    if missing:
        raise ScenarioError(f"scenario key '{path}': missing required key(s) {', '.join(missing)}")
    return out


def check_fault(path: str, m: dict) -> dict:
    """Validate one fault table: 'kind' plus that kind's keys (see FAULT_KEYS)."""
    kind = m.get("kind")
    if kind not in FAULT_KEYS:
        raise ScenarioError(f"scenario key '{path}.kind': expected one of "
                            f"{', '.join(FAULT_KEYS)}, got {kind!r}")
    req, opt = FAULT_KEYS[kind]
    for k in m:
        if k != "kind" and k not in req and k not in opt:
            raise ScenarioError(f"unknown scenario key '{path}.{k}' for a fault of kind '{kind}'; "
                                f"valid keys: kind, {', '.join(sorted({**req, **opt}))}")
    rest = {k: v for k, v in m.items() if k != "kind"}
    out = _check_table(path, rest, {**req, **opt}, set(opt))
    if "gyro" in out and not 0 <= out["gyro"] < N_GYRO:
        raise ScenarioError(f"scenario key '{path}.gyro': must be in 0..{N_GYRO - 1}")
    if "tracker" in out and out["tracker"] not in ("st1", "st2"):
        raise ScenarioError(f"scenario key '{path}.tracker': must be 'st1' or 'st2'")
    if "end_s" in out and out["end_s"] <= out["start_s"]:
        raise ScenarioError(f"scenario key '{path}.end_s': must be greater than start_s")
    return {"kind": kind, **out}


def merge(base: dict, over: dict) -> dict:
    """Deep merge: tables merge key-wise, every other value (lists included) is replaced."""
    out = {k: _copy(v) for k, v in base.items()}
    for k, v in over.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else _copy(v)
    return out


def _fmt(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, float):
        return repr(v)
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return str(v)


def to_toml(cfg: dict, resolved: dict | None = None) -> str:
    """Render a scenario as TOML with each key's doc as a comment.

    ``resolved`` (same layout) supplies values for optional keys absent from ``cfg``; they are
    printed commented out, for reference.
    """
    resolved = resolved or {}
    lines = ["# RADICAL-RT synth scenario (keys carry their units; see docs/scenarios.md)"]
    lines += _emit_keys(cfg, resolved, SPEC, "")
    for sec, spec in SPEC.items():
        if isinstance(spec, dict):
            lines += ["", f"[{sec}]"]
            lines += _emit_keys(cfg.get(sec, {}), resolved.get(sec, {}), spec, sec)
    for f in cfg.get("faults", []):
        lines += ["", "[[faults]]"] + [f"{k} = {_fmt(v)}" for k, v in f.items()]
    return "\n".join(lines) + "\n"


def _emit_keys(cfg: dict, resolved: dict, spec: dict, sec: str) -> list[str]:
    lines = []
    for key, f in spec.items():
        if isinstance(f, dict) or f.kind == "faults" or (key == "base" and key not in cfg):
            continue
        if f.kind == "moves":
            moves = cfg.get(key, resolved.get(key, []))
            prefix = "" if key in cfg else "# "
            lines.append(f"# {key}: {f.doc}")
            for m in moves:
                lines += [f"{prefix}[[{sec}.{key}]]"] + [f"{prefix}{k} = {_fmt(v)}" for k, v in m.items()]
            continue
        if key in cfg:
            lines.append(f"{key} = {_fmt(cfg[key])}  # {f.doc}")
        elif key in resolved:
            lines.append(f"# {key} = {_fmt(resolved[key])}  # {f.doc}")
    return lines
