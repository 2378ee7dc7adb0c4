"""Scenario texts shared by the engine tests: the short CI maneuver run of 2006216."""

from __future__ import annotations

MOVES = [("x", 10.0), ("x", -20.0), ("x", 10.0), ("z", 10.0), ("z", -20.0), ("z", 10.0),
         ("y", 30.0), ("y", -60.0), ("y", 30.0)]


def scenario(truth: str) -> str:
    lines = ['base = "2006216"', f'name = "ci-short-{truth}"', "duration_s = 1500.0",
             "[truth]", f'source = "{truth}"', "[maneuver]", "start_s = 60.0"]
    for axis, angle in MOVES:
        lines += ["[[maneuver.moves]]", f'axis = "{axis}"', f"angle_deg = {angle}", "hold_s = 60.0"]
    return "\n".join(lines) + "\n"
