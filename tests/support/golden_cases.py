"""The seeded scenarios of the golden outputs (:mod:`tests.support.golden`).

Each case function takes a scratch directory and returns (description, outputs, processor). They
cover what the engine does on the seeded scenarios of the suite and the clock matrix: a nominal
stream with slews while the SIRU clock locks, the same stream damaged, a gyro fault through
isolation, two timing cases of the robustness matrix (tick tags with read offset and jitter,
either sign of ε, a counter wrap and a reset) and two disjoint streams with a warm start.
"""

from __future__ import annotations

from pathlib import Path

from perf.fdi_cases import fault_toml, synth
from replayer.synth import synthesize
from studies.clock_matrix_cases import by_name, scenario

from .golden import run_streams
from .streams import damaged, input_messages, make_archive


def _nominal(d: Path):
    return input_messages(make_archive(d, "n", seed=3, duration=400))


def nominal_400(d: Path):
    out, sp = run_streams([_nominal(d)])
    return "2006216, seed 3, 400 s: slews while the SIRU clock locks", out, sp


def damaged_400(d: Path):
    out, sp = run_streams([damaged(_nominal(d))])
    return ("nominal_400 damaged: a 1 s SIRU gap, garbage, duplicates, time going backwards, a "
            "NaN quaternion"), out, sp


def fault_300(d: Path):
    text = fault_toml({"kind": "bias_step", "gyro": 1, "start_s": 120.0, "bias_deg_hr": 5.0},
                      duration=300.0, t_start=1000.0)
    out, sp = run_streams([input_messages(synth(text, d / "fault.mcap"))])
    return "300 s, gyro B bias step of 5 deg/hr at 120 s: alarm, isolation, exclusion", out, sp


def _clock(d: Path, name: str):
    case = by_name(name)
    path = d / f"{name}.mcap"
    synthesize(scenario(case), path)
    out, sp = run_streams([input_messages(path)])
    return f"clock matrix case {name} ({case.duration_s:g} s)", out, sp


def clock_issue_100(d: Path):
    return _clock(d, "q-issue+100")


def clock_tick9_100us(d: Path):
    return _clock(d, "q-tick.9-100us")


def two_streams(d: Path):
    a = input_messages(make_archive(d, "a", seed=5, duration=200, base="2005301"))
    b = input_messages(make_archive(d, "b", seed=6, duration=200, base="2006216"))
    out, sp = run_streams([a, b], start="warm")
    return "2005301 then 2006216, 200 s each, overlapping bus times, warm start", out, sp


CASES = {"nominal_400": nominal_400, "damaged_400": damaged_400, "fault_300": fault_300,
         "clock_issue_100": clock_issue_100, "clock_tick9_100us": clock_tick9_100us,
         "two_streams": two_streams}
