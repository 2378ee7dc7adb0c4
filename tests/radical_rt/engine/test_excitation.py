"""Excitation monitor (radical_rt.engine.excitation): warns when a maneuver leaves a group unexcited.

Covariance-only runs (the engine on noise-free data along the plan, mission.design) of ±30°
slews: about x and z only — the y components of the sense axes stay unobservable, λ, du, dv never
converge and the monitor must warn during the last slews (it is silent at rest) — and
about x, y and z, which must end converged with the warning cleared. ≈ 6 s.
"""

from __future__ import annotations

import numpy as np
import pytest

from mission.design import plan as planmod
from mission.design.covariance import new_engine, run_plan
from radical_rt.contract.flags import Flag, flag_names


def scenario(axes: str) -> dict:
    moves = [{"axis": ax, "angle_deg": a, "hold_s": 30.0} for ax in axes for a in (30.0, -60.0, 30.0)]
    return {"base": "2006216", "name": "ex", "duration_s": 2200.0,
            "maneuver": {"start_s": 420.0, "moves": moves}}


def run(axes: str):
    eng = new_engine()
    log = []
    update = eng.excitation.update

    def logged(*a):
        f = update(*a)
        log.append((eng.excitation.last, bool(f & Flag.EXCITATION_LOW)))
        return f

    eng.excitation.update = logged
    run_plan(planmod.plan_of(planmod.load(scenario(axes))), eng)
    return eng, log


def test_no_rotation_about_y_warns_for_the_scaled_axes():
    eng, log = run("xz")
    z_slews = [(r, w) for r, w in log if 1400 < r["t"] - 0 < 1530]  # the last z slew
    assert any(w and {"lam", "du", "dv"} <= set(r["not_excited"]) for r, w in z_slews)
    last = log[-1][0]
    assert not last["groups"]["lam"]["converged"]
    # the monitor names the missing axis: the sense axes' y components stay at their prior
    assert last["rotate_about"] == ["y"]
    assert last["axis_sigma_arcsec"]["y"] > 1000 > 1 > last["axis_sigma_arcsec"]["x"]
    assert "EXCITATION_LOW" in flag_names(int(Flag.EXCITATION_LOW))


def test_full_maneuver_ends_converged_and_clear():
    eng, log = run("xyz")
    r, warned = log[-1]
    assert not warned and all(v["converged"] for v in r["groups"].values())
    assert r["rotate_about"] == [] and max(r["axis_sigma_arcsec"].values()) < 5.0
    # while the y rotation runs, the joint scaled-axis gain is large
    gains = [r["groups"]["lam"]["gain"] for r, _w in log if 1000 < r["t"] < 1500]
    assert max(gains) > 1.0
    assert not eng.flags & Flag.EXCITATION_LOW


def test_rest_never_warns():
    eng = new_engine()
    run_plan(planmod.plan_of(planmod.load({"base": "2006216", "duration_s": 600.0,
                                           "maneuver": {"profile": "none"}})), eng)
    rep = eng.excitation.report()
    assert rep is not None and not rep["rotating"] and rep["not_excited"] == []
    assert np.isfinite(rep["groups"]["b"]["gain"])


def test_dashboard_line():
    from monitors.common import excitation_text

    eng, _log = run("xz")
    assert excitation_text(None) == ""
    line = excitation_text(eng.excitation.report())
    assert line.startswith("60 s") and "gain b" in line
    rep = dict(eng.excitation.report(), not_excited=["lam", "du"])
    assert "NOT EXCITED: lam, du" in excitation_text(rep)
    assert excitation_text(rep).endswith("(axes not yet turned about: y)")


def test_rotationrotation_angle_between_attitudes_matches_scipy_at_every_scale():
    """The monitor's accumulated rotation: the angle of p⁻¹∘q, pinned against scipy from 1e-8 rad
    (where 2·acos(|p·q|) keeps only half the digits) to nearly π."""
    from scipy.spatial.transform import Rotation

    from radical_rt.engine.excitation import rotation_angle_between

    rng = np.random.default_rng(11)
    for angle in (1e-8, 1e-6, 1e-4, 0.01, 0.5, 2.0, 3.1):
        p = Rotation.random(random_state=int(rng.integers(1 << 30)))
        axis = rng.normal(size=3)
        q = p * Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle)
        got = rotation_angle_between(p.as_quat(), q.as_quat())
        assert got == pytest.approx((p.inv() * q).magnitude(), rel=1e-9, abs=1e-15)
        assert got == pytest.approx(angle, rel=1e-7)
