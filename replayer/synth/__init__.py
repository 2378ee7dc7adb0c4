"""Synthetic MESSENGER-like truth and sensor simulation (independent of the filter models).

Public API: :func:`synthesize` (scenario → MCAP archive), :func:`load_scenario`,
:class:`~replayer.synth.maneuver.Profile` (closed-form truth attitude) and
:class:`ScenarioError`. The physics follows CONTRACT §1.4–1.5 with its own code; it never imports
the filter (``radical_rt.kernels.model``, ``filter``, ``params``). See docs/scenarios.md.
"""

from importlib import import_module

from .schema import ScenarioError

#: the public names and their modules, imported on first use (PEP 562): `radical` imports every
#: subcommand's module to build its parser, and the simulator's modules pull in scipy
_LAZY = {"SynthResult": "api", "synthesize": "api", "Move": "maneuver", "Profile": "maneuver",
         "BUILTINS": "scenario", "Scenario": "scenario", "load_scenario": "scenario"}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["BUILTINS", "Move", "Profile", "Scenario", "ScenarioError", "SynthResult",
           "load_scenario", "synthesize"]
