"""Maneuver profiles and the exact (closed-form) truth attitude.

A profile is a sequence of single-axis slews about body axes, each with a trapezoidal (ramped) rate
profile, separated by inertial holds. Within a slew about the fixed body axis ``e`` the body turns
by ``angle(s)`` (closed-form integral of the trapezoid), so the attitude is exact:

    q_inertial_from_body(t) = q_inertial_from_body(t_seg) * Rotation.from_rotvec(e * angle(t - t_seg))

i.e. ``R_body_from_inertial(t) = R(e·angle)ᵀ @ R_body_from_inertial(t_seg)`` and ``omega_body = e·rate``.
Times given to :class:`Profile` methods are bus times (s); the profile starts at ``t0`` (the run's
first bus time). Before ``t0`` and after the last move the body is inertially fixed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from radical_rt.contract.conventions import DEG

AXES = {"x": 0, "y": 1, "z": 2}


@dataclass(frozen=True)
class Move:
    """One slew: ``angle_deg`` (signed) about body ``axis`` ('x'|'y'|'z'), then ``hold_s`` of hold."""

    axis: str
    angle_deg: float
    hold_s: float = 0.0


def trapezoid_timing(angle: float, rate: float, ramp: float) -> tuple[float, float, float]:
    """Timing of a rest-to-rest slew of |angle| rad at max ``rate`` rad/s with ``ramp`` s ramps.

    Returns (t_ramp, t_cruise, peak_rate): ramps of t_ramp s at constant acceleration rate/ramp,
    cruise of t_cruise s at peak_rate. Short slews (|angle| < rate·ramp) are triangular.
    Duration = 2·t_ramp + t_cruise.
    """
    a_abs = abs(angle)
    if a_abs == 0.0:
        return 0.0, 0.0, 0.0
    if ramp <= 0.0:
        return 0.0, a_abs / rate, rate
    if a_abs >= rate * ramp:
        return ramp, a_abs / rate - ramp, rate
    t1 = math.sqrt(a_abs * ramp / rate)
    return t1, 0.0, rate * t1 / ramp


def _trapezoid_eval(s, a_abs, t1, tc, wp):
    """Angle and rate magnitudes at local times s (k,), per-element trapezoid parameters (k,).

    s is clipped to [0, duration]. Returns (angle (k,), rate (k,)), both ≥ 0.
    """
    dur = 2.0 * t1 + tc
    s = np.clip(s, 0.0, dur)
    acc = np.divide(wp, t1, out=np.zeros_like(wp), where=t1 > 0)
    ang = np.empty_like(s)
    rate = np.empty_like(s)
    m1 = s < t1
    m3 = s > t1 + tc
    m2 = ~(m1 | m3)
    ang[m1] = 0.5 * acc[m1] * s[m1] ** 2
    rate[m1] = acc[m1] * s[m1]
    ang[m2] = 0.5 * wp[m2] * t1[m2] + wp[m2] * (s[m2] - t1[m2])
    rate[m2] = wp[m2]
    r = dur[m3] - s[m3]
    ang[m3] = a_abs[m3] - 0.5 * acc[m3] * r**2
    rate[m3] = acc[m3] * r
    done = s >= dur
    ang[done] = a_abs[done]
    rate[done] = 0.0
    return ang, rate


class Profile:
    """Closed-form truth attitude for a list of :class:`Move` s.

    Parameters: ``moves``; ``q0_body_from_inertial`` (4,) scalar-last initial attitude; ``rate_deg_s``
    max slew rate; ``ramp_s`` ramp time; ``start_s`` hold before the first move; ``t0`` bus time
    of the run start (s). Segments (slews and holds) are tabulated once on construction.
    """

    def __init__(self, moves, q0_body_from_inertial, rate_deg_s=0.3, ramp_s=20.0, start_s=0.0,
                 t0=0.0):
        self.moves = tuple(moves)
        self.t0 = float(t0)
        rate = rate_deg_s * DEG
        begins, axes, angles, t1s, tcs, wps = [], [], [], [], [], []
        t = self.t0 + start_s
        for mv in self.moves:
            ang = mv.angle_deg * DEG
            t1, tc, wp = trapezoid_timing(ang, rate, ramp_s)
            begins.append(t)
            axes.append(AXES[mv.axis])
            angles.append(ang)
            t1s.append(t1)
            tcs.append(tc)
            wps.append(wp)
            t += 2.0 * t1 + tc + mv.hold_s
        self.begin = np.array(begins, dtype=float)
        self.axis = np.array(axes, dtype=int)
        self.angle = np.array(angles, dtype=float)
        self.t1 = np.array(t1s, dtype=float)
        self.tc = np.array(tcs, dtype=float)
        self.wp = np.array(wps, dtype=float)
        self.end_time = t  # bus time when the last move's hold ends
        self.r0_ib = Rotation.from_quat(q0_body_from_inertial).inv()
        self._seg_start_ib = self._tabulate_starts()

    @property
    def slew_end(self) -> np.ndarray:
        """Bus time at which each slew ends (n_moves,)."""
        return self.begin + 2.0 * self.t1 + self.tc

    def _tabulate_starts(self) -> Rotation:
        """q_inertial_from_body at the start of each move (index i), and after the last (index n)."""
        quats = [self.r0_ib.as_quat()]
        r = self.r0_ib
        for i in range(len(self.moves)):
            e = np.zeros(3)
            e[self.axis[i]] = 1.0
            r = r * Rotation.from_rotvec(e * self.angle[i])
            quats.append(r.as_quat())
        return Rotation.from_quat(np.array(quats))

    def _local(self, t):
        """Segment index (k,) in −1..n−1 (−1: before the first move) and signed angle/rate (k,)."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        idx = np.searchsorted(self.begin, t, side="right") - 1
        ang = np.zeros_like(t)
        rate = np.zeros_like(t)
        ok = idx >= 0
        if np.any(ok):
            i = idx[ok]
            a, w = _trapezoid_eval(t[ok] - self.begin[i], np.abs(self.angle[i]), self.t1[i],
                                   self.tc[i], self.wp[i])
            sgn = np.sign(self.angle[i])
            ang[ok] = sgn * a
            rate[ok] = sgn * w
        return idx, ang, rate

    def _axes(self, idx):
        """Unit body axis (k, 3) of the segments idx (zeros for idx = −1)."""
        e = np.zeros((idx.size, 3))
        ok = idx >= 0
        e[np.nonzero(ok)[0], self.axis[idx[ok]]] = 1.0
        return e

    def _r_ib(self, idx, ang):
        """q_inertial_from_body as a Rotation (k,) from segment indices and in-segment angles."""
        e = self._axes(idx)
        return self._seg_start_ib[np.maximum(idx, 0)] * Rotation.from_rotvec(e * ang[:, None])

    def truth_attitude(self, t):
        """Exact truth at bus times t (k,): (q_body_from_inertial (k, 4), omega_body (k, 3) rad/s)."""
        idx, ang, rate = self._local(t)
        q = self._r_ib(idx, ang).inv().as_quat()
        q *= np.where(q[:, 3:4] < 0.0, -1.0, 1.0)
        return q, self._axes(idx) * rate[:, None]

    def rotation_increment(self, t1, t2):
        """Exact rotation vector (k, 3) [rad, body axes] from body(t1) to body(t2), t1, t2 (k,).

        Satisfies q_inertial_from_body(t2) = q_inertial_from_body(t1) * from_rotvec(theta). Within
        one segment it is ``e·(angle(t2) − angle(t1))`` with no round-off from attitude products.
        """
        i1, a1, _ = self._local(t1)
        i2, a2, _ = self._local(t2)
        theta = self._axes(i2) * (a2 - a1)[:, None]
        cross = i1 != i2
        if np.any(cross):
            r1 = self._r_ib(i1[cross], a1[cross])
            r2 = self._r_ib(i2[cross], a2[cross])
            theta[cross] = (r1.inv() * r2).as_rotvec()
        return theta

    def timeline(self):
        """Human-readable rows (start_s, end_s, description) relative to t0, holds included."""
        rows = []
        t_prev = self.t0
        for i, mv in enumerate(self.moves):
            if self.begin[i] > t_prev:
                rows.append((t_prev - self.t0, self.begin[i] - self.t0, "hold"))
            end = self.slew_end[i]
            rows.append((self.begin[i] - self.t0, end - self.t0,
                         f"slew {mv.angle_deg:+g} deg about body {mv.axis}, "
                         f"peak {self.wp[i] / DEG:.3f} deg/s"))
            t_prev = end
        rows.append((t_prev - self.t0, math.inf, "hold (inertial) to end of run"))
        return rows


def pm(axis: str, amp_deg: float, hold_s: float) -> list[Move]:
    """The '±A' sequence about ``axis``: +A, −2A, +A (returns to start), ``hold_s`` after each."""
    return [Move(axis, amp_deg, hold_s), Move(axis, -2.0 * amp_deg, hold_s),
            Move(axis, amp_deg, hold_s)]


def _original() -> tuple[float, list[Move]]:
    h = 280.0
    return 200.0, [Move("x", 90.0, h), *pm("y", 30.0, h), *pm("z", 30.0, h), Move("x", -90.0, h)]


def _alternate() -> tuple[float, list[Move]]:
    h = 260.0
    return 200.0, [*pm("x", 30.0, h), *pm("y", 30.0, h), *pm("z", 30.0, h)]


def _messenger() -> tuple[float, list[Move]]:
    h = 240.0
    return 300.0, [*pm("x", 10.0, h), *pm("z", 10.0, h), Move("y", 360.0, 60.0),
                   Move("y", -360.0, 0.0)]


#: Built-in profiles: name -> (start_s, moves). Timelines are documented in docs/scenarios.md.
PROFILES = {"original": _original, "alternate": _alternate, "messenger": _messenger,
            "none": lambda: (0.0, [])}


def builtin_moves(name: str) -> tuple[float, list[Move]]:
    """(start_s, moves) of a built-in profile name (see :data:`PROFILES`)."""
    return PROFILES[name]()
