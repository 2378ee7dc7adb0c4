"""The one statement of RADICAL-RT's conventions (quaternions, frames, units, time).

Quaternions
    Stored scalar-last ``[x, y, z, w]``, unit norm, Hamilton product as in
    :class:`scipy.spatial.transform.Rotation`. ``q_X_from_Y`` maps Y-frame components to X-frame
    components: ``v_X = R(q_X_from_Y) @ v_Y``; composition ``q_X_from_Z = q_X_from_Y * q_Y_from_Z``.
    A rotation vector ``phi`` in frame F means ``Rotation.from_rotvec(phi)`` in F components.

Attitude error (filter)
    ``R_body_from_inertial_true = R(dtheta).T @ R_body_from_inertial_est``: the true body frame is
    the estimated body frame rotated by the small rotation vector ``dtheta`` (body axes). The
    update folds ``dtheta`` in with ``q <- rotvec_to_quat(-dtheta) * q``.

Frames
    ``inertial`` (J2000), ``body``, ``st1``, ``st2`` (tracker frames, boresight = tracker +z).
    ST1 is the body reference. ST2's misalignment ``phi2`` is a rotation vector in body axes with
    ``R_st2_from_body = R_st2_from_body_nom @ R(phi2).T``.

Units
    SI inside and on the wire: rad, rad/s, s. The paper's units (deg/hr, ppm, arcsec) appear only at
    the edges (summary file, reports, dashboards), converted with the constants below.

Time
    ``t_bus`` is spacecraft bus time in seconds (float64). MCAP log/publish times are
    ``round(t_bus * 1e9)`` ns. The SIRU has its own oscillator; its samples carry a 1 µs time-tag
    counter ``tt`` that wraps at 2**32.
"""

from __future__ import annotations

import math

ARCSEC = math.pi / 648000.0  # rad per arcsec
DEG_PER_HR = math.pi / 648000.0  # rad/s per deg/hr
PPM = 1e-6
DEG = math.pi / 180.0

SIRU_TT_TICK_S = 1e-6  # nominal time-tag tick
SIRU_TT_WRAP = 1 << 32  # time-tag counter modulus
SIRU_PERIOD_S = 0.01  # nominal sample period
SIRU_TICKS_PER_SAMPLE = 10000

NS_PER_S = 1_000_000_000


def t_to_ns(t_bus: float) -> int:
    """Bus time (s) to MCAP log_time (ns), per the contract: round(t_bus * 1e9)."""
    return int(round(t_bus * 1e9))


# Conversions between SI and the paper's units, per parameter group.
PAPER_UNITS = {"b": "deg/hr", "lam": "ppm", "mu": "ppm", "du": "arcsec", "dv": "arcsec",
               "phi2": "arcsec"}
SI_PER_PAPER_UNIT = {"b": DEG_PER_HR, "lam": PPM, "mu": PPM, "du": ARCSEC, "dv": ARCSEC,
                     "phi2": ARCSEC}


def to_paper_units(group: str, value_si):
    """Convert a parameter group's SI value(s) to the paper's units (deg/hr, ppm, arcsec)."""
    return value_si / SI_PER_PAPER_UNIT[group]


def from_paper_units(group: str, value_paper):
    """Convert a parameter group's value(s) in the paper's units to SI."""
    return value_paper * SI_PER_PAPER_UNIT[group]
