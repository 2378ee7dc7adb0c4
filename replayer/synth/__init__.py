"""Synthetic MESSENGER-like truth and sensor simulation (independent of the filter models).

Public API: :func:`synthesize` (scenario → MCAP archive), :func:`load_scenario`,
:class:`~replayer.synth.maneuver.Profile` (closed-form truth attitude) and
:class:`ScenarioError`. The physics follows CONTRACT §1.4–1.5 with its own code; it never imports
the filter (``radical_rt.kernels.model``, ``filter``, ``params``). See docs/scenarios.md.
"""

from .api import SynthResult, synthesize
from .maneuver import Move, Profile
from .scenario import BUILTINS, Scenario, load_scenario
from .schema import ScenarioError

__all__ = ["BUILTINS", "Move", "Profile", "Scenario", "ScenarioError", "SynthResult",
           "load_scenario", "synthesize"]
