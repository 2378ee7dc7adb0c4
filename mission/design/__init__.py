"""Maneuver design by covariance analysis (docs/design.md): `radical design`.

:mod:`.covariance` runs the engine without data along a planned attitude history,
:mod:`.analysis` reads the result (targets, time to target, poor directions, summary JSON),
:mod:`.constraints` the Sun pointing and tracker exclusion, :mod:`.plan` the scenario glue
(imports ``replayer.synth`` lazily), :mod:`.optimize` the search over a maneuver family.
"""
