"""Built-in scenarios, TOML loading, semantic validation and truth-parameter resolution.

``load_scenario(name_or_path)`` returns a :class:`Scenario`: the validated nested configuration
(paper units, as in the TOML) plus the resolved truth parameters in SI. Built-ins: ``2005300``,
``2005301``, ``2006216`` (the paper's Tables 2–7 rows, MESSENGER maneuver of Fig. 3) and
``original``, ``alternate`` (Fig. 2a/2b maneuvers, truth drawn uniformly on Table 1's [−L, L]),
``static`` (4 h inertial hold with every SIRU noise term on, for ``radical allan``).
"""

from __future__ import annotations

import json
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from radical_rt.contract.conventions import SI_PER_PAPER_UNIT

from . import maneuver
from .schema import (
    JITTER_DISTS,
    N_GYRO,
    TAG_MODES,
    TIMING_DEFAULTS,
    ScenarioError,
    check_tree,
    defaults,
    merge,
    siru_timing,
    to_toml,
)

TABLES_PATH = Path("/work/shared/data/messenger_tables.json")
_PKG_TABLES = Path(__file__).with_name("messenger_tables.json")

#: truth groups: scenario key (paper units) -> (SI group name, length)
GROUPS = {"b_deg_hr": ("b", N_GYRO), "lam_ppm": ("lam", N_GYRO), "mu_ppm": ("mu", N_GYRO),
          "du_arcsec": ("du", N_GYRO), "dv_arcsec": ("dv", N_GYRO), "phi2_arcsec": ("phi2", 3)}
TABLE_ROWS = ("2005300", "2005301", "2006216", "2005301-2006216")

BUILTINS: dict[str, dict] = {
    **{row: {"name": row, "seed": int(row), "duration_s": 7200.0,
             "maneuver": {"profile": "messenger"}, "truth": {"source": row}}
       for row in ("2005300", "2005301", "2006216")},
    "original": {"name": "original", "seed": 1001, "duration_s": 4000.0,
                 "maneuver": {"profile": "original"}, "truth": {"source": "uniform"}},
    "alternate": {"name": "alternate", "seed": 1002, "duration_s": 4000.0,
                  "maneuver": {"profile": "alternate"}, "truth": {"source": "uniform"}},
    # Inertial hold for gyro noise characterization (radical allan): no maneuver; angle random
    # walk, bias instability, bias random walk and quantization all on (docs/monitors.md).
    "static": {"name": "static", "seed": 952, "duration_s": 14400.0,
               "maneuver": {"profile": "none"}, "truth": {"source": "2006216"},
               "siru": {"bias_instability_deg_hr": 0.005}},
}


def load_tables() -> dict:
    """The paper's tables (messenger_tables.json): the shared copy, else a packaged copy."""
    for p in (TABLES_PATH, _PKG_TABLES):
        if p.exists():
            return json.loads(p.read_text())
    raise FileNotFoundError(f"messenger_tables.json not found at {TABLES_PATH}")


@dataclass
class Scenario:
    """A validated scenario.

    ``cfg``: nested dict (TOML layout, paper units); ``truth``: SI arrays {b (4,) rad/s, lam (4,),
    mu (4,), du (4,) rad, dv (4,) rad, phi2 (3,) rad} at the run start (before drifts/faults).
    """

    cfg: dict
    truth: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.cfg["name"]

    @property
    def seed(self) -> int:
        return self.cfg["seed"]

    def profile(self) -> maneuver.Profile:
        """The maneuver profile (closed-form truth attitude) of this scenario."""
        m = self.cfg["maneuver"]
        start, moves = maneuver.builtin_moves(m["profile"])
        if "moves" in m:
            moves = [maneuver.Move(x["axis"], x["angle_deg"], x.get("hold_s", 0.0)) for x in m["moves"]]
        return maneuver.Profile(moves, m["q0_body_from_inertial"], m["rate_deg_s"], m["ramp_s"],
                                m.get("start_s", start), t0=self.cfg["t_start_s"])

    def resolved_optionals(self) -> dict:
        """Values of the optional keys as resolved (for printing as comments)."""
        m = self.cfg["maneuver"]
        start, moves = maneuver.builtin_moves(m["profile"])
        truth = {k: (self.truth[g] / SI_PER_PAPER_UNIT[g]).round(6).tolist()
                 for k, (g, _) in GROUPS.items()} if self.cfg["truth"]["source"] in TABLE_ROWS else {}
        return {"maneuver": {"start_s": start, "moves": [
            {"axis": x.axis, "angle_deg": x.angle_deg, "hold_s": x.hold_s} for x in moves]},
            "truth": truth}

    def to_toml(self, timing_defaults: bool = False) -> str:
        """The full scenario as TOML (optional keys commented out with their resolved values).

        ``timing_defaults`` also lists the unset [siru] bus-read timing keys, commented out with
        their defaults (``--print-default``; the archive metadata leaves them out, so that
        archives of scenarios without them keep their bytes)."""
        resolved = self.resolved_optionals()
        if timing_defaults:
            resolved["siru"] = dict(TIMING_DEFAULTS)
        return to_toml(self.cfg, resolved)


def builtin_config(name: str) -> dict:
    """Full configuration dict of a built-in scenario."""
    if name not in BUILTINS:
        raise ScenarioError(f"unknown built-in scenario '{name}'; built-ins: {', '.join(BUILTINS)}")
    return merge(defaults(), BUILTINS[name])


def load_scenario(spec: str | Path | dict, seed: int | None = None, duration: float | None = None,
                  vehicle: str | None = None) -> Scenario:
    """Load a built-in name, a TOML file path, or a mapping (TOML layout); apply overrides."""
    if isinstance(spec, dict):
        data = dict(spec)
    elif str(spec) in BUILTINS:
        data = {"base": str(spec)}
    else:
        data = _read_toml(Path(spec))
    data = check_tree(data)
    base = data.pop("base", None)
    cfg = merge(builtin_config(base) if base else defaults(), data)
    for key, val in (("seed", seed), ("duration_s", duration), ("vehicle", vehicle)):
        if val is not None:
            cfg[key] = check_tree({key: val})[key]
    check_semantics(cfg)
    return Scenario(cfg, resolve_truth(cfg))


def _read_toml(path: Path) -> dict:
    if not path.exists():
        raise ScenarioError(f"scenario '{path}' is neither a built-in ({', '.join(BUILTINS)}) "
                            "nor an existing TOML file")
    try:
        return tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: invalid TOML: {exc}") from None


def _require(ok: bool, key: str, msg: str) -> None:
    if not ok:
        raise ScenarioError(f"scenario key '{key}': {msg}")


def check_semantics(cfg: dict) -> None:
    """Range and consistency checks on a full configuration. Raises ScenarioError naming the key."""
    _require(bool(re.fullmatch(r"[a-z0-9_-]+", cfg["vehicle"])), "vehicle", "must match [a-z0-9_-]+")
    _require(cfg["duration_s"] > 0, "duration_s", "must be > 0")
    _require(cfg["t_start_s"] >= 0, "t_start_s", "must be ≥ 0 (MCAP log times are unsigned)")
    m = cfg["maneuver"]
    _require(m["profile"] in maneuver.PROFILES, "maneuver.profile",
             f"must be one of {', '.join(maneuver.PROFILES)}")
    _require(m["rate_deg_s"] > 0, "maneuver.rate_deg_s", "must be > 0")
    _require(m["ramp_s"] >= 0, "maneuver.ramp_s", "must be ≥ 0")
    _require(m.get("start_s", 0.0) >= 0, "maneuver.start_s", "must be ≥ 0")
    _require(bool(np.linalg.norm(m["q0_body_from_inertial"]) > 1e-6), "maneuver.q0_body_from_inertial",
             "must be a non-zero quaternion")
    for i, mv in enumerate(m.get("moves", [])):
        _require(mv["axis"] in maneuver.AXES, f"maneuver.moves[{i}].axis", "must be x, y or z")
        _require(mv.get("hold_s", 0.0) >= 0, f"maneuver.moves[{i}].hold_s", "must be ≥ 0")
    t = cfg["truth"]
    _require(t["source"] in (*TABLE_ROWS, "uniform", "zero"), "truth.source",
             f"must be one of {', '.join(TABLE_ROWS)}, uniform, zero")
    _check_siru(cfg["siru"])
    _check_trackers(cfg["trackers"], cfg["siru"])
    th, out = cfg["thermal"], cfg["output"]
    _require(th["rate_hz"] > 0, "thermal.rate_hz", "must be > 0")
    _require(th["tau_s"] > 0, "thermal.tau_s", "must be > 0")
    _require(th["sensor_noise_C"] >= 0, "thermal.sensor_noise_C", "must be ≥ 0")
    for k in ("attitude_hz", "params_hz"):
        _require(out[k] > 0, f"output.{k}", "must be > 0")
    _require(out["chunk_s"] >= 1.0, "output.chunk_s", "must be ≥ 1")
    _check_rates(cfg)
    _check_gaps(cfg["faults"])


def _check_gaps(faults: list[dict]) -> None:
    gaps = sorted((f["start_s"], f["end_s"], i) for i, f in enumerate(faults) if f["kind"] == "gap")
    for (_, e0, _), (s1, _, i) in zip(gaps[:-1], gaps[1:], strict=True):
        _require(s1 >= e0, f"faults[{i}].start_s", "data gaps must not overlap")


def _check_siru(s: dict) -> None:
    _require(s["period_s"] > 0, "siru.period_s", "must be > 0")
    _require(abs(s["eps_ppm"]) < 1000, "siru.eps_ppm", "must be within ±1000 ppm")
    _require(0 <= s["phase_s"] < s["period_s"], "siru.phase_s", "must be in [0, period_s)")
    _require(0 <= s["sample_jitter_s"] <= s["period_s"] / 20, "siru.sample_jitter_s",
             "must be in [0, period_s/20]")
    _require(s["bus_period_s"] > 0, "siru.bus_period_s", "must be > 0")
    _require(0 <= s["read_jitter_s"] <= s["bus_period_s"] / 20, "siru.read_jitter_s",
             "must be in [0, bus_period_s/20]")
    _require(0 <= s["tt0"] < 2**32, "siru.tt0", "must be in [0, 2**32)")
    _require(all(x > 0 for x in s["tt_reset_s"]), "siru.tt_reset_s", "times must be > 0")
    for k in ("arw_deg_sqrt_hr", "bias_rw_rad_s_sqrt_s", "quantum_arcsec",
              "bias_instability_deg_hr"):
        _require(s[k] >= 0, f"siru.{k}", "must be ≥ 0")
    _require(s["batch"] >= 1, "siru.batch", "must be ≥ 1")
    _check_read_timing(s)


def _check_read_timing(s: dict) -> None:
    """The optional bus-read timing keys (docs/scenarios.md, "Bus-read timing")."""
    tm, bus = siru_timing(s), s["bus_period_s"]
    _require(tm["tag_mode"] in TAG_MODES, "siru.tag_mode", f"must be one of {', '.join(TAG_MODES)}")
    _require(tm["read_jitter_dist"] in JITTER_DISTS, "siru.read_jitter_dist",
             f"must be one of {', '.join(JITTER_DISTS)}")
    _require(2.0 < tm["read_jitter_dof"] <= 1e6, "siru.read_jitter_dof",
             "must be in (2, 1e6] (a finite variance, so that read_jitter_s is its 1σ)")
    _require(0 <= tm["read_offset_s"] <= bus / 5, "siru.read_offset_s", "must be in [0, bus_period_s/5]")
    _require(tm["read_offset_s"] == 0 or tm["tag_mode"] == "tick", "siru.read_offset_s",
             "needs tag_mode = 'tick' (with tag_mode = 'read' the tag is the read instant)")
    _require(0 <= tm["late_read_prob"] <= 1, "siru.late_read_prob", "must be in [0, 1]")
    _require(0 <= tm["late_read_max_s"] <= bus / 4, "siru.late_read_max_s",
             "must be in [0, bus_period_s/4]")
    _require(tm["late_read_prob"] == 0 or tm["late_read_max_s"] > 0, "siru.late_read_max_s",
             "must be > 0 when late_read_prob > 0")


def _check_trackers(tr: dict, s: dict) -> None:
    _require(tr["latency_s"] >= 0, "trackers.latency_s", "must be ≥ 0")
    for k in ("sigma_xy_arcsec", "sigma_z_arcsec", "invalid_error_deg"):
        _require(tr[k] >= 0, f"trackers.{k}", "must be ≥ 0")
    _require(1 <= tr["n_stars_min"] <= tr["n_stars_start"] <= tr["n_stars_max"],
             "trackers.n_stars_start", "need 1 ≤ n_stars_min ≤ n_stars_start ≤ n_stars_max")
    _require(tr["n_stars_ref"] >= 1, "trackers.n_stars_ref", "must be ≥ 1")
    for k in ("n_stars_step_prob", "invalid_prob", "dropout_prob"):
        _require(0 <= tr[k] <= 1, f"trackers.{k}", "must be in [0, 1]")


def _check_rates(cfg: dict) -> None:
    """Every periodic stream must fall on bus ticks: its period a whole number of bus periods."""
    bus = cfg["siru"]["bus_period_s"]
    for key, hz in (("trackers.rate_hz", cfg["trackers"]["rate_hz"]),
                    ("thermal.rate_hz", cfg["thermal"]["rate_hz"]),
                    ("output.attitude_hz", cfg["output"]["attitude_hz"]),
                    ("output.params_hz", cfg["output"]["params_hz"])):
        _require(hz > 0, key, "must be > 0")
        ratio = 1.0 / (hz * bus)
        _require(abs(ratio - round(ratio)) < 1e-9 and round(ratio) >= 1, key,
                 f"period must be a whole number of bus periods ({bus} s)")


def resolve_truth(cfg: dict) -> dict[str, np.ndarray]:
    """Truth parameters (SI) at the run start from ``truth.source`` and the explicit overrides.

    'uniform' draws each group on [−f·L, f·L] (Table 1's L, f = uniform_fraction) from a stream
    seeded by the scenario seed; 'zero' sets all to 0; a table row takes the paper's estimates.
    """
    t = cfg["truth"]
    tables = load_tables()
    out: dict[str, np.ndarray] = {}
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(cfg["seed"], spawn_key=(7,))))
    for key, (group, n) in GROUPS.items():
        if t["source"] in TABLE_ROWS:
            paper = np.array(tables["estimates"][t["source"]][key], dtype=float)
        elif t["source"] == "uniform":
            lim = tables["table1_initial_uniform_L"][key] * t["uniform_fraction"]
            paper = rng.uniform(-lim, lim, size=n)
        else:
            paper = np.zeros(n)
        if key in t:
            paper = np.asarray(t[key], dtype=float)
        out[group] = paper * SI_PER_PAPER_UNIT[group]
    return out


def describe_truth(truth: dict[str, np.ndarray]) -> dict[str, list[float]]:
    """Truth parameters in paper units (deg/hr, ppm, arcsec), rounded for reports."""
    return {g: [round(float(x), 6) for x in v / SI_PER_PAPER_UNIT[g]] for g, v in truth.items()}


def print_default(name: str | None) -> str:
    """TOML text of a built-in scenario (default 2006216), optional keys shown as comments."""
    return load_scenario(name or "2006216").to_toml(timing_defaults=True)
