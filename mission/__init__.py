"""Tools built on both the engine (``radical_rt``) and the simulator (``replayer``): maneuver
design by covariance analysis (:mod:`mission.design`, ``radical design``) and the end-to-end
demo (:mod:`mission.demo`, ``make demo``).

Neither ``radical_rt`` nor ``replayer`` imports this package (import-linter checks it); its
subcommand reaches the ``radical`` command line through the ``radical.commands`` entry points.
"""
