"""From a scenario (built-in name or TOML, the format `radical synth` runs) to a design run.

``replayer.synth`` (the maneuver model: exact truth attitude and rates) is imported lazily inside
the functions: loading the simulator (its archive writer, its compiled code) is left to the runs
that need a scenario, not to ``radical --help`` or the covariance code.
"""

from __future__ import annotations

import copy
from collections.abc import Callable

from mission.design.constraints import Pointing, tracker_visibility
from mission.design.covariance import History, Plan, clock_lock_s, new_engine, run_plan


def load(spec, duration: float | None = None):
    """The validated :class:`replayer.synth.scenario.Scenario` of a built-in name, a TOML path or
    a mapping (raises ``replayer.synth.schema.ScenarioError`` with a clear message)."""
    from replayer.synth.scenario import load_scenario

    return load_scenario(spec, duration=duration)


def tables() -> dict:
    """The paper's tables (messenger_tables.json)."""
    from replayer.synth.scenario import load_tables

    return load_tables()


def plan_of(sc, t0: float | None = None, warm: bool = False,
            pointing: Pointing | None = None, geo=None) -> Plan:
    """The :class:`Plan` of a scenario: its maneuver profile from bus time ``t0`` (default the
    scenario's ``t_start_s``), its tracker set-up (rate, latency, on/off; the star count's
    long-run distribution, uniform on [n_stars_min, n_stars_max] when it wanders, and the
    expected share of invalid and missing samples) and SIRU clock
    (lock at the second sawtooth wrap, the first after a warm start); with ``pointing`` the
    trackers are blinded inside their Sun exclusion cone."""
    cfg = copy.deepcopy(sc.cfg)
    if t0 is not None:
        cfg["t_start_s"] = float(t0)
    sc = type(sc)(cfg, sc.truth)
    prof = sc.profile()
    s, tr = cfg["siru"], cfg["trackers"]
    lock = clock_lock_s(s["period_s"], s["eps_ppm"], s["phase_s"], s["bus_period_s"],
                        wraps=1 if warm else 2)
    visible = None
    if pointing is not None and pointing.exclusion_deg > 0 and geo is not None:
        visible = tracker_visibility(prof, pointing.sun(cfg["maneuver"]["q0_body_from_inertial"]),
                                     geo, pointing.exclusion_deg)
    cycle = None
    if tr["n_stars_step_prob"] > 0 and tr["n_stars_max"] > tr["n_stars_min"]:
        # the star count's random walk (reflecting on [min, max]) is uniform in the long run
        cycle = tuple(range(int(tr["n_stars_min"]), int(tr["n_stars_max"]) + 1))
    keep = max(0.0, 1.0 - tr["invalid_prob"] - tr["dropout_prob"])
    return Plan(prof, cfg["t_start_s"], cfg["duration_s"], siru_period_s=s["period_s"],
                tracker_rate_hz=tr["rate_hz"], latency_s=tr["latency_s"],
                n_stars=int(tr["n_stars_start"]), trackers=(bool(tr["st1"]), bool(tr["st2"])),
                lock_s=lock, tracker_visible=visible, n_stars_cycle=cycle, tracker_keep=keep)


def warm_engine(prior_spec="2006216", table=None, progress: Callable | None = None):
    """An engine after a cold design run of the prior calibration (default the as-flown
    2006216 maneuver) and the warm start with the §3.1 bump (``Engine.warm_start``, the
    table's ``bump_*``), as ``radical process A.mcap B.mcap`` does between streams.
    Returns (engine, prior History)."""
    eng = new_engine(table)
    prior = run_plan(plan_of(load(prior_spec)), eng, progress=progress)
    eng.warm_start(bump=True)
    return eng, prior


def design(sc, table=None, engine=None, record_dt: float = 10.0, pointing: Pointing | None = None,
           progress: Callable | None = None) -> tuple[History, Plan]:
    """Covariance analysis of scenario ``sc``: cold (engine None) or continuing ``engine`` (a
    warm-started engine, its stream shifted to start after the engine's time)."""
    warm = engine is not None
    eng = engine if warm else new_engine(table)
    t0 = max(sc.cfg["t_start_s"], eng.t + 1000.0) if warm else None
    plan = plan_of(sc, t0=t0, warm=warm, pointing=pointing, geo=eng.geo)
    return run_plan(plan, eng, record_dt=record_dt, progress=progress), plan
