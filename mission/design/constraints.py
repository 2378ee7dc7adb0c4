"""Pointing constraints of a calibration maneuver: Sun on a body axis, tracker Sun exclusion.

The Sun direction is an inertial unit vector ``sun_inertial``; by default it is the constrained
body axis at the initial attitude (the spacecraft starts Sun-pointed, e.g. MESSENGER's sunshade:
inside 0.85 AU its body y axis must stay within 12° of the Sun). A tracker (boresight = its +z,
in body axes ``R_stj_from_bodyᵀ e_z``) within ``exclusion_deg`` of the Sun is blinded: its samples
are dropped from the covariance analysis, and a maneuver that blinds both at once is flagged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

AXES = {"x": 0, "y": 1, "z": 2}


@dataclass
class Pointing:
    """sun_axis: body axis that must point near the Sun ('x'|'y'|'z', sign by ``sun_sign``);
    sun_max_deg: its largest allowed angle from the Sun (inf: unconstrained); exclusion_deg: the
    trackers' Sun exclusion half-cone (0: none); sun_inertial (3,) or None (from q0)."""

    sun_axis: str = "y"
    sun_sign: float = 1.0
    sun_max_deg: float = float("inf")
    exclusion_deg: float = 0.0
    sun_inertial: np.ndarray | None = None

    def sun(self, q0_body_from_inertial) -> np.ndarray:
        """The inertial Sun unit vector (3,)."""
        if self.sun_inertial is not None:
            s = np.asarray(self.sun_inertial, float)
            return s / np.linalg.norm(s)
        e = np.zeros(3)
        e[AXES[self.sun_axis]] = self.sun_sign
        return Rotation.from_quat(q0_body_from_inertial).inv().apply(e)


def sun_body(trajectory, t, sun_inertial) -> np.ndarray:
    """The Sun direction in body axes (k, 3) at bus times t (k,)."""
    q, _ = trajectory.truth_attitude(np.asarray(t, float))
    return Rotation.from_quat(q).apply(sun_inertial)


def tracker_visibility(trajectory, sun_inertial, geo, exclusion_deg: float):
    """callable(j, epochs) → bool (k,): tracker j sees stars (Sun outside its exclusion cone)."""
    bores = {1: geo.R_st1_from_body.T @ np.array([0, 0, 1.0]),
             2: geo.R_st2_from_body_nom.T @ np.array([0, 0, 1.0])}
    cos_ex = np.cos(np.radians(exclusion_deg))

    def visible(j, epochs):
        if exclusion_deg <= 0:
            return np.ones(len(epochs), bool)
        s = sun_body(trajectory, epochs, sun_inertial)
        return s @ bores[j] < cos_ex

    return visible


def check(trajectory, t0: float, duration_s: float, q0, pointing: Pointing, geo,
          step_s: float = 1.0) -> dict:
    """Worst-case pointing over the plan (sampled every step_s): the largest Sun angle of the
    constrained axis [deg], the smallest Sun angle of each tracker boresight [deg], the time both
    trackers are blinded [s], and ``ok``."""
    t = t0 + np.arange(0.0, duration_s + step_s, step_s)
    s_inert = pointing.sun(q0)
    s = sun_body(trajectory, t, s_inert)
    e = np.zeros(3)
    e[AXES[pointing.sun_axis]] = pointing.sun_sign
    ang = np.degrees(np.arccos(np.clip(s @ e, -1, 1)))
    out = {"sun_axis_max_deg": float(ang.max())}
    blind = np.zeros(len(t), bool) | True
    for j, R in ((1, geo.R_st1_from_body), (2, geo.R_st2_from_body_nom)):
        b = R.T @ np.array([0, 0, 1.0])
        a = np.degrees(np.arccos(np.clip(s @ b, -1, 1)))
        out[f"st{j}_sun_min_deg"] = float(a.min())
        blind &= a < pointing.exclusion_deg
    out["both_blind_s"] = float(blind.sum() * step_s)
    out["ok"] = bool(out["sun_axis_max_deg"] <= pointing.sun_max_deg + 1e-9
                     and out["both_blind_s"] == 0.0)
    return out
