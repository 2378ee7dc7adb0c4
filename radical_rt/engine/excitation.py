"""Excitation monitor: is the recent motion informative for each parameter group?

Per parameter group g (b, λ, μ, du, dv, φ2) the monitor keeps, every ``period_s`` = 10 s (at a
closed parity sum, a point the reference and the compiled paths share, so the flag is
bit-identical between them; ≈ 50 µs per step inside a 2-hour run, 5 µs per second of
telemetry: the numbers come from one compiled call, :mod:`radical_rt.kernels.information`), the log of
the UD variances of the group's states and the body rotation angle accumulated since the start
(the angle between successive attitude estimates). Over a sliding window of ``window_s`` s:

* ``gain`` = mean over the group's states of ln(σ(t − W)/σ(t)): the information the updates
  added in the window, normalised by what the filter already knew (0: nothing learnt; 0.69: σ
  halved). Process noise makes it slightly negative when nothing is learnt. For λ, du and dv,
  which together form the scaled sense axes a_i, the gain is the larger of that and the same
  per-state mean of ½ ln det of their joint (12-state) covariance block: a rotation about a new
  body axis informs every a_iᵀe at once, long before any marginal σ falls (that needs all three
  axes).
* ``converged``: every state of the group below its convergence threshold (``conv_*``).
* a group is **not excited** when the body turned by at least ``rotation_min_deg`` in the window
  (a calibration maneuver is under way), the group is not converged, and ``gain < gain_min``.

With the nominal triads (``triads``), each step also reports ``axis_sigma_arcsec``: the rms over
the gyros of σ(a_iᵀe_k), the sense axes' components along body x, y and z, and ``rotate_about``:
the body axes whose σ is still above the misalignment threshold — the axes the maneuver has not
(yet) turned about, which is what tells a maneuver without a y rotation from one that has not
reached its y rotation yet.

If any group is not excited, bit 20 ``EXCITATION_LOW`` of ``flags`` is set (and cleared as soon as
none is). Example: a maneuver without any rotation about body y leaves the y components of the
sense axes unobservable: λ, du, dv stay unconverged with zero gain through every x and z slew
(docs/design.md). All SI; the monitor never touches the covariance.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np

from radical_rt.contract.conventions import ARCSEC
from radical_rt.contract.flags import Flag
from radical_rt.contract.state import PARAM_GROUPS, StateLayout
from radical_rt.kernels.information import excitation_numbers, excitation_work

_BIT = int(Flag.EXCITATION_LOW)


def rotation_angle_between(p: np.ndarray, q: np.ndarray) -> float:
    """Rotation angle [rad] between two unit quaternions (4,) scalar-last: 2·atan2(|v|, |w|) of
    p⁻¹∘q, written out in floats (no BLAS: the same bits on every CPU). Well conditioned for
    small angles, where 2·acos(|p·q|) loses half the digits (an angle of 1e-5 rad came out
    different in the 5th digit between two CPUs)."""
    px, py, pz, pw = p.tolist()
    qx, qy, qz, qw = q.tolist()
    w = pw * qw + px * qx + py * qy + pz * qz
    vx = pw * qx - qw * px - (py * qz - pz * qy)
    vy = pw * qy - qw * py - (pz * qx - px * qz)
    vz = pw * qz - qw * pz - (px * qy - py * qx)
    return 2.0 * math.atan2(math.sqrt(vx * vx + vy * vy + vz * vz), abs(w))


class ExcitationMonitor:
    """Sliding-window information gain per parameter group (see the module docstring)."""

    def __init__(self, layout: StateLayout, window_s: float = 60.0, gain_min: float = 0.02,
                 rotation_min_deg: float = 2.0, period_s: float = 10.0,
                 triads: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> None:
        self.window_s, self.gain_min = float(window_s), float(gain_min)
        self.period_s = float(period_s)
        self.rotation_min = math.radians(rotation_min_deg)
        self._slices = [(g, layout[g]) for g in PARAM_GROUPS]
        self._axis_idx = np.concatenate([np.arange(layout[g].start, layout[g].stop)
                                         for g in ("lam", "du", "dv")])
        # rows of a_iᵀe_k in the error state (none without the triads: no axis report)
        self._G = (np.zeros((0, layout.n_states)) if triads is None
                   else _axis_rows(layout, *triads))
        self._row_var = np.empty(self._G.shape[0])
        self._work = excitation_work(len(self._axis_idx))
        #: each group's range in the parameter vector (the convergence test)
        self._par_ranges = [(sl.start - 3, sl.stop - 3) for _g, sl in self._slices]
        self._axis_groups = [k for k, (g, _) in enumerate(self._slices) if g in ("lam", "du", "dv")]
        self.clear()

    def clear(self) -> None:
        """Forget the history (after a cold or warm start)."""
        self._hist: deque = deque()  # (t [s], ln var of the parameter states, rotation [rad])
        self._rot = 0.0
        self._t_last = -math.inf
        self._q_last: np.ndarray | None = None
        self.last: dict[str, Any] | None = None

    def due(self, t: float) -> bool:
        """Whether a step is due at engine time t (every ``period_s``; the caller then builds P)."""
        return t >= self._t_last + self.period_s

    def next_step(self) -> float:
        """The engine time [s] from which :meth:`due` is true."""
        return self._t_last + self.period_s

    def update(self, t: float, P: np.ndarray, q_body_from_inertial: np.ndarray,
               conv_var: np.ndarray, flags: int) -> int:
        """One step at engine time t [s]: P (ns, ns) the covariance (from the UD factors), the
        attitude estimate (4,) scalar-last (the rotation since the last step is the angle between
        the two attitudes), conv_var (ns − 3,) the convergence thresholds² of the parameter
        states; returns ``flags`` with EXCITATION_LOW set or cleared."""
        if t <= self._t_last:
            return flags
        q = np.asarray(q_body_from_inertial, float)
        if self._q_last is not None:
            self._rot += rotation_angle_between(self._q_last, q)
        self._q_last = q.copy()
        self._t_last = t
        # ln var of every state and the joint term of the scaled axes: a rotation about a new
        # axis informs a_iᵀe there, a combination of λ, du, dv, before any marginal σ falls
        lv = np.empty(P.shape[0] + 1)
        excitation_numbers(P, self._axis_idx, self._G, lv, self._row_var, self._work)
        h = self._hist
        h.append((t, lv, self._rot))
        while len(h) > 1 and h[1][0] <= t - self.window_s:
            h.popleft()
        t0, lv0, rot0 = h[0]
        rotating = self._rot - rot0 >= self.rotation_min and t - t0 >= 0.5 * self.window_s
        half = (0.5 * (lv0 - lv)).tolist()
        joint = half[-1] / len(self._axis_idx)
        gains = [sum(half[sl]) / (sl.stop - sl.start) for _g, sl in self._slices]
        for k in self._axis_groups:
            gains[k] = max(gains[k], joint)
        above = [v > c for v, c in zip(P.diagonal()[3:].tolist(), conv_var.tolist(), strict=True)]
        conv = [True not in above[a:b] for a, b in self._par_ranges]  # no state above
        groups, warn = {}, []
        for (g, _sl), gain, conv_g in zip(self._slices, gains, conv, strict=True):
            excited = gain >= self.gain_min
            groups[g] = {"gain": round(gain, 5), "converged": conv_g, "excited": excited}
            if rotating and not conv_g and not excited:
                warn.append(g)
        self.last = {"t": t, "window_s": t - t0, "rotation_deg": math.degrees(self._rot - rot0),
                     "rotating": rotating, "groups": groups, "not_excited": warn}
        if len(self._G):
            self.last.update(self._axes(conv_var))
        return (flags | _BIT) if warn else (flags & ~_BIT)

    def _axes(self, conv_var: np.ndarray) -> dict[str, Any]:
        """σ of the sense axes' components along body x, y, z (rms over the gyros of
        σ(a_iᵀe_k), arcsec; from the step's diag(G P Gᵀ)) and the body axes still to be rotated
        about (σ above the misalignment convergence threshold)."""
        var = self._row_var.tolist()  # row k·n + i: a_iᵀe_k
        n = len(var) // 3
        rms = [math.sqrt(max(sum(var[k * n:(k + 1) * n]) / n, 0.0)) / ARCSEC for k in range(3)]
        thr = math.sqrt(float(conv_var[self._axis_idx[-1] - 3])) / ARCSEC
        return {"axis_sigma_arcsec": {c: round(v, 4) for c, v in zip("xyz", rms, strict=True)},
                "rotate_about": [c for c, v in zip("xyz", rms, strict=True) if v > thr]}

    def report(self) -> dict[str, Any] | None:
        """The last step's result (the ``excitation`` map of diag), None before the first."""
        return self.last


def _axis_rows(layout: StateLayout, W: np.ndarray, U: np.ndarray, V: np.ndarray) -> np.ndarray:
    """(3n, ns), row k·n + i: the error-state row of a_iᵀe_k (scaled axis a_i = (1+λ')w_i − du'v_i − dv'u_i,
    body axis k): w_ik at λ_i, −v_ik at du_i, −u_ik at dv_i (nominal triads W, U, V (3, n))."""
    n = W.shape[1]
    G = np.zeros((3, n, layout.n_states))
    for i in range(n):
        G[:, i, layout["lam"].start + i] = W[:, i]
        G[:, i, layout["du"].start + i] = -V[:, i]
        G[:, i, layout["dv"].start + i] = -U[:, i]
    return G.reshape(3 * n, layout.n_states)
