"""Star trackers ST1/ST2 (CONTRACT §1.4, §1.5) and the ST2 baseplate thermal model.

At bus time t a tracker reports ``q_stj_from_inertial`` of the attitude at ``t − latency``:

    R_st1_from_inertial = R_ST1_FROM_BODY @ R_body_from_inertial
    R_st2_from_inertial = R_ST2_FROM_BODY_NOM @ R(phi2(t))ᵀ @ R_body_from_inertial

with noise: a small rotation ``n`` in the tracker frame (``R_meas = R(n) @ R_true``), n ~ N(0,
diag(σ_xy², σ_xy², σ_z²)·n_ref/n_stars). The star count does a slow ±1 random walk in
[n_min, n_max]. Invalid samples (valid=false) carry a corrupted q (an error of ½–1 × invalid_error_deg
about a random axis); dropped samples are not sent.
Temperatures follow a first-order rise T(t) = T0 + rise·(1 − exp(−(t − t_start)/τ)) and
``phi2(t) = phi2_0 + k_temp·(T2(t) − T2(t_start))``. SI inside (rad, s); °C for temperatures.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from radical_rt.contract.conventions import ARCSEC, DEG
from radical_rt.contract.geometry import R_ST1_FROM_BODY, R_ST2_FROM_BODY_NOM

_R_ST1 = Rotation.from_matrix(R_ST1_FROM_BODY)
_R_ST2_NOM = Rotation.from_matrix(R_ST2_FROM_BODY_NOM)


class Thermal:
    """Baseplate/SIRU temperatures (°C) and the temperature-driven ST2 misalignment (rad)."""

    def __init__(self, thermal: dict, t_start: float, phi2_0: np.ndarray):
        self.c = thermal
        self.t_start = t_start
        self.phi2_0 = np.asarray(phi2_0, dtype=float)
        self.k = np.asarray(thermal["k_temp_arcsec_per_C"]) * ARCSEC  # rad/°C

    def _rise(self, t: np.ndarray) -> np.ndarray:
        return 1.0 - np.exp(-np.maximum(t - self.t_start, 0.0) / self.c["tau_s"])

    def temps(self, t: np.ndarray) -> dict[str, np.ndarray]:
        """True temperatures (m,) °C at bus times t (m,): st1, st2 baseplates and SIRU."""
        r = self._rise(t)
        return {name: self.c[f"{name}_C0"] + self.c[f"{name}_rise_C"] * r
                for name in ("st1", "st2", "siru")}

    def phi2(self, t: np.ndarray) -> np.ndarray:
        """True ST2 misalignment (m, 3) rad, body axes, at bus times t (m,)."""
        dT = self.c["st2_rise_C"] * self._rise(t)
        return self.phi2_0[None, :] + dT[:, None] * self.k[None, :]


def st_from_inertial(which: str, q_body_from_inertial: np.ndarray,
                     phi2: np.ndarray | None = None) -> Rotation:
    """Noise-free R_stj_from_inertial (m rotations) from q_body_from_inertial (m, 4), phi2 (m, 3)."""
    r_bi = Rotation.from_quat(q_body_from_inertial)
    if which == "st1":
        return _R_ST1 * r_bi
    return _R_ST2_NOM * Rotation.from_rotvec(phi2).inv() * r_bi


def star_walk(n0: int, lo: int, hi: int, p: float, u: np.ndarray) -> np.ndarray:
    """Star counts (m,) of a clipped ±1 random walk starting after n0; u (m, 2) uniform draws.

    A step happens with probability p (u[:, 0] < p), up or down with equal odds (u[:, 1]).
    """
    step = np.where(u[:, 0] < p, np.where(u[:, 1] < 0.5, -1, 1), 0)
    out = np.empty(u.shape[0], dtype=np.int64)
    n, last = n0, 0
    for i in np.nonzero(step)[0].tolist():
        out[last:i] = n
        n = min(max(n + int(step[i]), lo), hi)
        last = i
    out[last:] = n
    return out


class Tracker:
    """One tracker's measurement process. ``rngs``: streams 'stars', 'noise', 'valid', 'drop',
    'corrupt' (each drawn a fixed number of times per sample, so chunking does not matter)."""

    def __init__(self, name: str, tr: dict, outages: list[tuple[float, float]], rngs: dict):
        self.name = name
        self.tr = tr
        self.outages = outages
        self.rngs = rngs
        self.n_stars = tr["n_stars_start"]

    def flags(self, t: np.ndarray):
        """(valid (m,) bool, sent (m,) bool) for samples at bus times t (m,)."""
        valid = self.rngs["valid"].random(t.size) >= self.tr["invalid_prob"]
        sent = self.rngs["drop"].random(t.size) >= self.tr["dropout_prob"]
        for a, b in self.outages:
            sent &= ~((t >= a) & (t < b))
        return valid, sent

    def measure(self, t: np.ndarray, r_true: Rotation):
        """Measurements at bus times t (m,) of the true R_stj_from_inertial (m rotations).

        Returns (q (m, 4) scalar-last, n_stars (m,), valid (m,), sent (m,)).
        """
        tr = self.tr
        stars = star_walk(self.n_stars, tr["n_stars_min"], tr["n_stars_max"],
                          tr["n_stars_step_prob"], self.rngs["stars"].random((t.size, 2)))
        if t.size:
            self.n_stars = int(stars[-1])
        scale = np.sqrt(tr["n_stars_ref"] / stars)[:, None]
        sig = np.array([tr["sigma_xy_arcsec"], tr["sigma_xy_arcsec"], tr["sigma_z_arcsec"]]) * ARCSEC
        n = self.rngs["noise"].standard_normal((t.size, 3)) * sig[None, :] * scale
        valid, sent = self.flags(t)
        c = self.rngs["corrupt"].standard_normal((t.size, 4))
        axis = c[:, :3] / np.linalg.norm(c[:, :3], axis=1, keepdims=True)
        bad_angle = tr["invalid_error_deg"] * DEG * (0.5 + 0.5 * np.tanh(np.abs(c[:, 3])))
        n[~valid] = axis[~valid] * bad_angle[~valid, None]
        q = (Rotation.from_rotvec(n) * r_true).as_quat()
        q *= np.where(q[:, 3:4] < 0.0, -1.0, 1.0)
        return q, stars, valid, sent
