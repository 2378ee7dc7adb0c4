"""Fixtures shared by the FDI tests."""

from __future__ import annotations

import pytest

from perf.fdi_cases import fault_toml, synth


@pytest.fixture(scope="package")
def short_fault(tmp_path_factory):
    """400 s, bus time from 1000 s, gyro B bias step of 5 deg/hr at 120 s (at rest, cold start)."""
    d = tmp_path_factory.mktemp("fdi_node")
    text = fault_toml({"kind": "bias_step", "gyro": 1, "start_s": 120.0, "bias_deg_hr": 5.0},
                      duration=400.0, t_start=1000.0)
    return synth(text, d / "short.mcap")
