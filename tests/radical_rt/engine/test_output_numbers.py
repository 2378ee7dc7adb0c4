"""Engine.output_numbers: the telemetry fields est, sigma, att_sigma and latency from one compiled
call give the maps of estimates(), sigmas(), att_sigma() and latency_estimate(), bit for bit, at
every packet hook of a run; the packets read them through it (stream.telemetry.NUMBER_FIELDS)."""

from __future__ import annotations

import numpy as np

from radical_rt.apps.batch import process
from radical_rt.engine.filter import Engine
from radical_rt.stream.telemetry import NUMBER_FIELDS


def _separately(e: Engine) -> dict:
    return {"est": e.estimates(), "sigma": e.sigmas(), "att_sigma": e.att_sigma(),
            "latency": e.latency_estimate()}


def test_one_call_gives_the_separate_maps_at_every_hook(archives, monkeypatch):
    calls = []
    one_call = Engine.output_numbers

    def checked(self):
        got = one_call(self)
        var = self.ws.var.copy()
        want = _separately(self)  # (latency_estimate rewrites ws.var: the same values)
        assert set(got) == NUMBER_FIELDS
        assert repr(got) == repr(want)  # (repr: every float exactly, NaN and −0.0 included)
        assert var.tobytes() == self.ws.var.tobytes()
        calls.append(self.t)
        return got

    monkeypatch.setattr(Engine, "output_numbers", checked)
    summary = process([str(archives["a60"])], None)
    assert summary["counters"]["st1_used"] > 100
    assert len(calls) > 50  # (one per 1-Hz hook: medium, large and diag share it)


def test_cold_engine():
    e = Engine()
    assert repr(e.output_numbers()) == repr(_separately(e))
    assert np.isfinite(e.output_numbers()["latency"]["sigma_s"])
