"""``radical node --gil-switch-ms``: the default and the refused values (the interval itself is
measured by perf/bench_fleet_capacity.py, perf/README.md "Fleet capacity")."""

from __future__ import annotations

import argparse

from radical_rt.apps import node_cli


def _check(*a: str) -> str | None:
    p = argparse.ArgumentParser()
    node_cli.add_arguments(p)
    return node_cli._check(p.parse_args(["--vehicle", "a", *a]))  # noqa: SLF001


def test_gil_switch_interval_option():
    p = argparse.ArgumentParser()
    node_cli.add_arguments(p)
    assert p.parse_args(["--vehicle", "a"]).gil_switch_ms == node_cli.GIL_SWITCH_MS == 0.5
    assert _check("--gil-switch-ms", "2") is None
    for bad in ("0", "-1", "1000"):
        assert "--gil-switch-ms" in (_check("--gil-switch-ms", bad) or "")
