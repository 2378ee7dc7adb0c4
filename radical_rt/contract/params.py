"""Default and active parameter tables of the RADICAL engine.

The table is the one place where tuning lives. Names carry their units (paper units at this edge:
arcsec, deg/hr, ppm); :meth:`ParamTable.si` converts everything to SI for the engine. The active
table changes only through :meth:`ParamTable.set` (validated, all-or-nothing) and
:meth:`ParamTable.reset` (active ← default). TOML files give overrides by name::

    [params]
    st_sigma_cross_arcsec = 3.2
    bump_lam_ppm = [75, 500, 75, 75]

Initial variance rule (paper §2.3, notes §9.1): initial errors are uniform on [−L, L]; the paper's
garbled "3L2 … reflects 3 sigma" is read as P0 = 3·L² (filter 1σ = √3·L, three times the σ of the
uniform distribution). ``init_var_rule`` selects "3L2" (default), "L2/3" or "(L/3)2".
"""

from __future__ import annotations

import copy
import math
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from radical_rt.contract.conventions import ARCSEC, DEG, DEG_PER_HR, PPM

#: τ's prior 1σ never goes below this (a zero UD diagonal is not a valid factor): "frozen" [s]
LATENCY_SIGMA_FLOOR_S = 1e-9
INIT_VAR_RULES = {"3L2": 3.0, "L2/3": 1.0 / 3.0, "(L/3)2": 1.0 / 9.0}


class ParamError(ValueError):
    """An invalid parameter name, type, shape or value; the message names the parameter."""


@dataclass
class Params:
    """Engine parameters (paper units where named so). See module docstring for the rules."""

    # Star trackers: 1σ at `st_ref_stars` tracked stars, scaled by sqrt(st_ref_stars / n_stars).
    st_sigma_cross_arcsec: float = 3.2
    st_sigma_bore_arcsec: float = 29.0
    st_ref_stars: float = 9.0
    st_min_stars: int = 3
    latency_st_s: float = 0.115  # tracker epoch = t_bus − latency (paper: 0.11 s shift + 5 ms)
    # Residual latency state τ (true − configured latency, s; docs/engine.md §5): prior 1σ and
    # random-walk density. 0 for both freezes τ at 0 (the configured latency is then trusted).
    latency_sigma0_s: float = 0.03
    q_latency_s_sqrt_s: float = 1.0e-6
    st_stale_s: float = 1.0  # no valid sample for this long → STj_STALE
    # Gyros.
    arw_deg_sqrt_hr: float = 1.5e-4  # angle random walk
    quant_arcsec: float = 0.01  # delta-angle quantum (parity window noise q²/6)
    gyro_gap_s: float = 0.5  # a gyro interval longer than this is a gap → GYRO_GAP + warm start
    parity_window: int = 100  # gyro samples summed per parity update (may span tracker epochs)
    prop_window: int = 10  # gyro samples per time-update window (closed early at tracker epochs)
    # Tracker updates do not calibrate the gyros (Schmidt consider) while the epoch uncertainty of
    # the gyro time line, times the body rate, exceeds this fraction of the tracker noise variance.
    timing_consider_s: float = 1e-4
    parity_lag_s: float = 10.0  # a closed parity sum is processed this much later (docs/engine.md)
    # Errors-in-variables control: the summed body increment enters the λ, μ, du, dv columns only
    # in proportion to its significance at this many sigma (docs/engine.md).
    regressor_k_sigma: float = 3.0
    # Process noise (random walks). Paper: 0.001 ppm/√s (λ, μ), 0.001″/√s (δu, δv), 0.002″/√s (φ2).
    # Bias: not given by the paper; 2e-6 deg/hr/√s ≈ 1e-11 rad/s/√s (a slow rate random walk).
    q_b_deg_hr_sqrt_s: float = 2.0e-6
    q_lam_ppm_sqrt_s: float = 0.001
    q_mu_ppm_sqrt_s: float = 0.001
    q_misalign_arcsec_sqrt_s: float = 0.001
    q_phi2_arcsec_sqrt_s: float = 0.002
    # Initial errors: uniform on [−L, L] (paper Table 1); variance per init_var_rule.
    L_b_deg_hr: float = 3.0
    L_lam_ppm: float = 5000.0
    L_mu_ppm: float = 100.0
    L_du_arcsec: float = 3600.0
    L_dv_arcsec: float = 3600.0
    L_phi2_arcsec: float = 1800.0
    init_var_rule: str = "3L2"
    att_init_scale: float = 2.0  # initial attitude σ = scale × tracker σ (tracker axes mapped to body)
    # Warm-start covariance bump (paper §3.1), 1σ per state.
    bump_phi2_arcsec: list[float] = field(default_factory=lambda: [50.0, 10.0, 10.0])
    bump_b_deg_hr: list[float] = field(default_factory=lambda: [0.05] * 4)
    bump_lam_ppm: list[float] = field(default_factory=lambda: [75.0, 500.0, 75.0, 75.0])
    bump_mu_ppm: list[float] = field(default_factory=lambda: [8.0, 8.0, 8.0, 30.0])
    bump_du_arcsec: list[float] = field(default_factory=lambda: [15.0] * 4)
    bump_dv_arcsec: list[float] = field(default_factory=lambda: [15.0] * 4)
    bump_mode: str = "add"  # "add" (Agee-Turner, Δσ² added) or "scale" (σ multiplied)
    # Residual editing: reject when the normalized innovation squared exceeds the gate.
    gate_st_nis: float = 30.0  # χ²(3): P(false reject) ≈ 1.4e-6 per frame
    gate_parity_nis: float = 25.0  # χ²(1) = (5σ)²
    edit_enabled: bool = True
    # Parity fault detection, isolation and reconfiguration (radical_rt/fdi/monitor.py, docs/fdi.md).
    fdi_enabled: bool = True
    fdi_false_alarm_per_hr: float = 1e-3  # design false-alarm rate of the parity detector [1/h]
    fdi_guard_ratio: float = 4.0  # σ²/R above this: calibration-dominated, sequential tests held
    fdi_isolation_error_prob: float = 1e-6  # isolation needs a log-likelihood margin ln(1/p)
    fdi_auto_exclude: bool = True  # exclude an isolated gyro (and roll back its fault's effect)
    # Convergence: all 1σ below these thresholds → mode "converged".
    conv_b_deg_hr: float = 0.01
    conv_lam_ppm: float = 20.0
    conv_mu_ppm: float = 20.0
    conv_misalign_arcsec: float = 5.0
    conv_phi2_arcsec: float = 1.0
    conv_phi2_bore_arcsec: float = 2.0


GROUP_BUMP = {"b": "bump_b_deg_hr", "lam": "bump_lam_ppm", "mu": "bump_mu_ppm",
              "du": "bump_du_arcsec", "dv": "bump_dv_arcsec", "phi2": "bump_phi2_arcsec"}
#: the allowed values of the string-valued parameters
CHOICES = {"init_var_rule": tuple(INIT_VAR_RULES), "bump_mode": ("add", "scale")}
_LIST_LEN = {"bump_phi2_arcsec": 3}


#: Valid range [lo, hi] (inclusive, the parameter's own units; list parameters: every element) of
#: every numeric parameter. The bounds keep every kernel loop bounded and every division and
#: exponential finite (issue 23): e.g. σ and L > 0 (a zero UD diagonal is not a factor), windows
#: of at most 1000 / 100 000 samples, a false-alarm rate the thresholds can invert.
RANGES: dict[str, tuple[float, float]] = {
    "st_sigma_cross_arcsec": (1e-3, 3600.0), "st_sigma_bore_arcsec": (1e-3, 36000.0),
    "st_ref_stars": (1.0, 100.0), "st_min_stars": (0, 100), "latency_st_s": (0.0, 10.0),
    "latency_sigma0_s": (0.0, 1.0), "q_latency_s_sqrt_s": (0.0, 1e-2), "st_stale_s": (1e-3, 3600.0),
    "arw_deg_sqrt_hr": (0.0, 10.0), "quant_arcsec": (0.0, 100.0), "gyro_gap_s": (1e-3, 3600.0),
    "parity_window": (1, 100_000), "prop_window": (1, 1000), "timing_consider_s": (0.0, 10.0),
    "parity_lag_s": (0.0, 600.0), "regressor_k_sigma": (0.0, 100.0),
    "q_b_deg_hr_sqrt_s": (0.0, 1.0), "q_lam_ppm_sqrt_s": (0.0, 100.0),
    "q_mu_ppm_sqrt_s": (0.0, 100.0), "q_misalign_arcsec_sqrt_s": (0.0, 100.0),
    "q_phi2_arcsec_sqrt_s": (0.0, 100.0),
    "L_b_deg_hr": (1e-6, 3600.0), "L_lam_ppm": (1e-3, 1e5), "L_mu_ppm": (1e-3, 1e5),
    "L_du_arcsec": (1e-3, 36000.0), "L_dv_arcsec": (1e-3, 36000.0), "L_phi2_arcsec": (1e-3, 36000.0),
    "att_init_scale": (0.1, 1000.0),
    "bump_phi2_arcsec": (0.0, 36000.0), "bump_b_deg_hr": (0.0, 3600.0), "bump_lam_ppm": (0.0, 1e5),
    "bump_mu_ppm": (0.0, 1e5), "bump_du_arcsec": (0.0, 36000.0), "bump_dv_arcsec": (0.0, 36000.0),
    "gate_st_nis": (1e-3, 1e6), "gate_parity_nis": (1e-3, 1e6),
    "fdi_false_alarm_per_hr": (1e-12, 3600.0), "fdi_guard_ratio": (1e-3, 1e6),
    "fdi_isolation_error_prob": (1e-12, 0.5),
    "conv_b_deg_hr": (0.0, 3600.0), "conv_lam_ppm": (0.0, 1e6), "conv_mu_ppm": (0.0, 1e6),
    "conv_misalign_arcsec": (0.0, 36000.0), "conv_phi2_arcsec": (0.0, 36000.0),
    "conv_phi2_bore_arcsec": (0.0, 36000.0),
}


def _check_value(name: str, value: Any, default: Any, n_gyro: int) -> Any:
    """Validate one parameter against the type of its default and its :data:`RANGES` entry;
    return the normalized value (ParamError naming the parameter otherwise)."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ParamError(f"{name}: expected true/false, got {value!r}")
        return value
    if isinstance(default, str):
        if not isinstance(value, str) or value not in CHOICES.get(name, (value,)):
            raise ParamError(f"{name}: must be one of {CHOICES[name]}, got {value!r}")
        return value
    if isinstance(default, list):
        n = _LIST_LEN.get(name, n_gyro)
        if not isinstance(value, (list, tuple)) or len(value) != n:
            raise ParamError(f"{name}: expected a list of {n} numbers, got {_short(value)}")
        return [_check_value(name, v, 0.0, n_gyro) for v in value]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ParamError(f"{name}: expected a number, got {_short(value)}")
    try:
        fvalue = float(value)
    except OverflowError:  # an int beyond float range
        raise ParamError(f"{name}: {_short(value)} is out of range") from None
    if not math.isfinite(fvalue):
        raise ParamError(f"{name}: must be finite, got {value!r}")
    lo, hi = RANGES.get(name, (0.0, math.inf))
    if not lo <= fvalue <= hi:
        raise ParamError(f"{name}: must be in [{lo:g}, {hi:g}], got {_short(value)}")
    if isinstance(default, int) and not isinstance(default, bool):
        if int(value) != value:
            raise ParamError(f"{name}: expected an integer, got {value!r}")
        return int(value)
    return fvalue


def _short(value: Any) -> str:
    """repr of a value, cut to 60 characters (error messages stay one short line)."""
    r = repr(value)
    return r if len(r) <= 60 else r[:57] + "..."


def ranges_table() -> str:
    """The Markdown table of every parameter: default and valid range (docs/node.md)."""
    rows = ["| parameter | default | valid range |", "|---|---|---|"]
    for f in fields(Params):
        d = getattr(Params(), f.name)
        if isinstance(d, bool):
            rng = "true / false"
        elif isinstance(d, str):
            rng = " / ".join(CHOICES[f.name])
        else:
            lo, hi = RANGES[f.name]
            rng = f"[{lo:g}, {hi:g}]" + (" each" if isinstance(d, list) else "")
            rng += " integer" if isinstance(d, int) else ""
        rows.append(f"| `{f.name}` | {d} | {rng} |")
    return "\n".join(rows)


class ParamTable:
    """Default and active parameter tables; the engine reads :attr:`active`."""

    def __init__(self, defaults: Params | None = None, n_gyro: int = 4) -> None:
        self.n_gyro = n_gyro
        self.default = copy.deepcopy(defaults) if defaults is not None else Params()
        self.active = copy.deepcopy(self.default)

    @staticmethod
    def names() -> list[str]:
        return [f.name for f in fields(Params)]

    def set(self, updates: dict[str, Any]) -> None:
        """Validate every update first, then apply all of them (an invalid one changes nothing)."""
        if not isinstance(updates, dict):
            raise ParamError(f"params must be a map of name → value, got {type(updates).__name__}")
        checked = {}
        for name, value in updates.items():
            if name not in self.names():
                raise ParamError(f"unknown parameter {name!r}; valid names: {', '.join(self.names())}")
            checked[name] = _check_value(name, value, getattr(self.default, name), self.n_gyro)
        for name, value in checked.items():
            setattr(self.active, name, value)

    def reset(self) -> None:
        """Active table ← default table."""
        self.active = copy.deepcopy(self.default)

    def as_dict(self, which: str = "active") -> dict[str, Any]:
        src = self.active if which == "active" else self.default
        return {name: copy.deepcopy(getattr(src, name)) for name in self.names()}

    @classmethod
    def from_toml(cls, path: str | Path, n_gyro: int = 4) -> ParamTable:
        """Load defaults from a TOML file's ``[params]`` table (or top level). Clear errors."""
        try:
            doc = tomllib.loads(Path(path).read_text())
        except FileNotFoundError:
            raise ParamError(f"{path}: no such file") from None
        except tomllib.TOMLDecodeError as exc:
            raise ParamError(f"{path}: not valid TOML: {exc}") from None
        body = doc.get("params", doc)
        table = cls(n_gyro=n_gyro)
        try:
            table.set(dict(body))
        except ParamError as exc:
            raise ParamError(f"{path}: {exc}") from None
        table.default = copy.deepcopy(table.active)
        return table


@dataclass(frozen=True)
class SIParams:
    """The active table in SI, in the form the engine uses (see :func:`to_si`)."""

    st_sigma: tuple[float, float, float]  # rad, tracker axes (x, y, z=boresight) at st_ref_stars
    st_ref_stars: float
    st_min_stars: int
    latency_st_s: float
    st_stale_s: float
    arw_var_per_s: float  # rad²/s
    quant_var: float  # rad² (parity window noise q²/6)
    gyro_gap_s: float
    parity_window: int
    prop_window: int
    regressor_k_sigma: float
    parity_lag_s: float
    timing_consider_s: float
    q_params: tuple[float, ...]  # per parameter state incl. τ, variance growth per second (SI²/s)
    p0_params: tuple[float, ...]  # initial variances of the parameter states incl. τ (SI²)
    att_init_scale: float
    bump_sigma: dict[str, tuple[float, ...]]  # SI 1σ per group
    bump_mode: str
    gate_st_nis: float
    gate_parity_nis: float
    edit_enabled: bool
    conv_sigma: tuple[float, ...]  # per parameter state incl. τ (inf: not tested), SI


def to_si(p: Params, n_gyro: int = 4) -> SIParams:
    """Convert a :class:`Params` table to SI for the engine (parameter states in state order)."""
    n = n_gyro
    qb, ql, qm = p.q_b_deg_hr_sqrt_s * DEG_PER_HR, p.q_lam_ppm_sqrt_s * PPM, p.q_mu_ppm_sqrt_s * PPM
    qa, qp = p.q_misalign_arcsec_sqrt_s * ARCSEC, p.q_phi2_arcsec_sqrt_s * ARCSEC
    q = ([qb**2] * n + [ql**2] * n + [qm**2] * n + [qa**2] * (2 * n) + [qp**2] * 3
         + [p.q_latency_s_sqrt_s**2])
    k = INIT_VAR_RULES[p.init_var_rule]
    L = ([p.L_b_deg_hr * DEG_PER_HR] * n + [p.L_lam_ppm * PPM] * n + [p.L_mu_ppm * PPM] * n
         + [p.L_du_arcsec * ARCSEC] * n + [p.L_dv_arcsec * ARCSEC] * n + [p.L_phi2_arcsec * ARCSEC] * 3)
    conv = ([p.conv_b_deg_hr * DEG_PER_HR] * n + [p.conv_lam_ppm * PPM] * n + [p.conv_mu_ppm * PPM] * n
            + [p.conv_misalign_arcsec * ARCSEC] * (2 * n)
            + [p.conv_phi2_arcsec * ARCSEC] * 2 + [p.conv_phi2_bore_arcsec * ARCSEC]
            + [math.inf])  # τ: observable only while turning, not part of the convergence test
    unit = {"b": DEG_PER_HR, "lam": PPM, "mu": PPM, "du": ARCSEC, "dv": ARCSEC, "phi2": ARCSEC}
    bump = {g: tuple(v * unit[g] for v in getattr(p, name)) for g, name in GROUP_BUMP.items()}
    arw = p.arw_deg_sqrt_hr * DEG / 60.0  # deg/√hr → rad/√s
    return SIParams(
        st_sigma=(p.st_sigma_cross_arcsec * ARCSEC, p.st_sigma_cross_arcsec * ARCSEC,
                  p.st_sigma_bore_arcsec * ARCSEC),
        st_ref_stars=p.st_ref_stars, st_min_stars=p.st_min_stars, latency_st_s=p.latency_st_s,
        st_stale_s=p.st_stale_s, arw_var_per_s=arw**2, quant_var=(p.quant_arcsec * ARCSEC) ** 2 / 6.0,
        gyro_gap_s=p.gyro_gap_s, parity_window=p.parity_window, prop_window=p.prop_window, regressor_k_sigma=p.regressor_k_sigma, parity_lag_s=p.parity_lag_s, timing_consider_s=p.timing_consider_s, q_params=tuple(q),
        p0_params=tuple(k * x * x for x in L) + (max(p.latency_sigma0_s, LATENCY_SIGMA_FLOOR_S) ** 2,),
        att_init_scale=p.att_init_scale, bump_sigma=bump,
        bump_mode=p.bump_mode, gate_st_nis=p.gate_st_nis, gate_parity_nis=p.gate_parity_nis,
        edit_enabled=p.edit_enabled, conv_sigma=tuple(conv))
