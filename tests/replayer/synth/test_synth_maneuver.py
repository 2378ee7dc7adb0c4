"""Truth attitude of the maneuver profiles: closed form vs an independent composition with scipy,
vs numerical integration of omega, exact rotation increments, and the built-in timelines."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import quad
from scipy.spatial.transform import Rotation as R

from replayer.synth.maneuver import Move, Profile, builtin_moves, trapezoid_timing

DEG = np.pi / 180
Q0 = [0.1, -0.3, 0.4, np.sqrt(1 - 0.26)]
E = {"x": [1.0, 0, 0], "y": [0, 1.0, 0], "z": [0, 0, 1.0]}


def rate_oracle(s: float, angle: float, rate: float, ramp: float) -> float:
    """Signed rate of a rest-to-rest trapezoid (written independently of the simulator)."""
    a = abs(angle)
    if a >= rate * ramp:
        t1, wp = ramp, rate
    else:
        t1 = np.sqrt(a * ramp / rate)
        wp = rate * t1 / ramp
    tc = a / wp - t1
    if s <= 0 or s >= 2 * t1 + tc:
        return 0.0
    w = wp * min(s / t1, 1.0, (2 * t1 + tc - s) / t1)
    return float(np.sign(angle) * w)


def attitude_oracle(moves, start_s, rate, ramp, t) -> R:
    """q_inertial_from_body at time t by composing each move's rotation (angle by quadrature)."""
    r = R.from_quat(Q0).inv()
    t_m = start_s
    for mv in moves:
        ang = mv.angle_deg * DEG
        t1, tc, _ = trapezoid_timing(ang, rate, ramp)
        dur = 2 * t1 + tc
        s = min(max(t - t_m, 0.0), dur)
        done = quad(rate_oracle, 0.0, s, args=(ang, rate, ramp), points=[t1, t1 + tc], limit=200)[0]
        r = r * R.from_rotvec(np.array(E[mv.axis]) * done)
        t_m += dur + mv.hold_s
    return r


@pytest.mark.parametrize("angle_deg", [10.0, -20.0, 360.0, 3.0, -0.5])
def test_trapezoid_reaches_angle_with_bounded_rate(angle_deg):
    prof = Profile([Move("z", angle_deg, 5.0)], Q0, rate_deg_s=0.3, ramp_s=20.0)
    t = np.linspace(-1.0, prof.end_time + 1.0, 20001)
    q, w = prof.truth_attitude(t)
    assert np.all(np.abs(w[:, 2]) <= 0.3 * DEG + 1e-15)
    assert np.all(w[:, :2] == 0.0)
    total = prof.rotation_increment(t[:1], t[-1:])[0]
    expect = np.deg2rad(angle_deg) if abs(angle_deg) < 180 else 0.0  # 360° is the identity
    assert np.allclose(total, [0, 0, expect], atol=1e-12)
    # rate is the derivative of the angle (central differences on the exact angle; near a ramp
    # corner the difference quotient errs by at most acceleration·h/2)
    h = 1e-4
    th = prof.rotation_increment(t - h, t + h)[:, 2] / (2 * h)
    assert np.max(np.abs(th - w[:, 2])) < (0.3 * DEG / 20.0) * h / 2 + 1e-11


@pytest.mark.parametrize("name", ["messenger", "original", "alternate"])
def test_closed_form_matches_independent_composition(name):
    start, moves = builtin_moves(name)
    prof = Profile(moves, Q0, 0.3, 20.0, start)
    rng = np.random.default_rng(5)
    t = np.sort(rng.uniform(0, prof.end_time + 100, 40))
    q, _ = prof.truth_attitude(t)
    for ti, qi in zip(t, q, strict=True):
        oracle = attitude_oracle(moves, start, 0.3 * DEG, 20.0, ti).inv()
        assert (R.from_quat(qi) * oracle.inv()).magnitude() < 1e-9


def test_attitude_vs_rk4_integration_of_omega():
    """Integrate q_inertial_from_body' = ½ q ⊗ (ω, 0) with RK4 from omega_body alone."""
    start, moves = builtin_moves("original")
    prof = Profile(moves, Q0, 0.3, 20.0, start)
    dt, t0, t1 = 0.05, 150.0, 1500.0  # covers holds, +90° x and the ±30° y slews
    tn = np.arange(t0, t1 + dt / 2, dt)
    w_n = prof.truth_attitude(tn)[1]
    w_mid = prof.truth_attitude(tn[:-1] + dt / 2)[1]

    def qdot(q, w):
        x, y, z, s = q
        return 0.5 * np.array([s * w[0] + y * w[2] - z * w[1], s * w[1] + z * w[0] - x * w[2],
                               s * w[2] + x * w[1] - y * w[0], -x * w[0] - y * w[1] - z * w[2]])

    q = R.from_quat(prof.truth_attitude([t0])[0][0]).inv().as_quat()
    for i in range(tn.size - 1):
        k1 = qdot(q, w_n[i])
        k2 = qdot(q + dt / 2 * k1, w_mid[i])
        k3 = qdot(q + dt / 2 * k2, w_mid[i])
        k4 = qdot(q + dt * k3, w_n[i + 1])
        q = q + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    exact = R.from_quat(prof.truth_attitude([t1])[0][0]).inv()
    err = (R.from_quat(q / np.linalg.norm(q)) * exact.inv()).magnitude()
    assert err < 1e-8, err



def _messenger():
    start, moves = builtin_moves("messenger")
    return Profile(moves, Q0, 0.3, 20.0, start)


@settings(max_examples=60, deadline=None)
@given(st.floats(0, 5000), st.floats(1e-4, 700))
def test_rotation_increment_composes(t1, span):
    prof = _messenger()
    a, b = np.array([t1]), np.array([t1 + span])
    theta = prof.rotation_increment(a, b)
    r1 = R.from_quat(prof.truth_attitude(a)[0]).inv()
    r2 = R.from_quat(prof.truth_attitude(b)[0]).inv()
    # q_inertial_from_body(t2) = q_inertial_from_body(t1) * from_rotvec(theta)
    assert (r1 * R.from_rotvec(theta)).approx_equal(r2, atol=1e-10).all()


def test_rotation_increment_sign_is_body_rate():
    prof = _messenger()
    t = np.array([330.0])  # cruising at +0.3 deg/s about body x
    w = prof.truth_attitude(t)[1][0]
    assert np.allclose(w, [0.3 * DEG, 0, 0])
    theta = prof.rotation_increment(t, t + 0.01)[0]
    assert np.allclose(theta, w * 0.01, rtol=1e-12)


def test_messenger_timeline():
    prof = _messenger()
    ends = prof.slew_end
    # y-rate sign change (end of +360 y, start of -360 y) between 50 and 60 minutes
    iy = [i for i, m in enumerate(prof.moves) if m.axis == "y"]
    assert 50 * 60 <= ends[iy[0]] and prof.begin[iy[1]] <= 60 * 60
    assert ends[-1] < 7200
    # ±A sequences return to the start: the final attitude is the initial one
    q = prof.truth_attitude([0.0, 7200.0])[0]
    assert R.from_quat(q[0]).approx_equal(R.from_quat(q[1]), atol=1e-12)
    rates = prof.truth_attitude(np.arange(0, 7200, 0.5))[1]
    assert np.isclose(np.abs(rates).max(), 0.3 * DEG)


@pytest.mark.parametrize("name", ["original", "alternate"])
def test_paper_profiles_fit_4000_s(name):
    start, moves = builtin_moves(name)
    prof = Profile(moves, Q0, 0.3, 20.0, start)
    assert prof.slew_end[-1] <= 4000.0
    q = prof.truth_attitude([0.0, 4000.0])[0]
    assert R.from_quat(q[0]).approx_equal(R.from_quat(q[1]), atol=1e-12)
