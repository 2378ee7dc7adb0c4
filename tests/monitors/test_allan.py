"""`radical allan` on the simulator's static scenario: ARW and bias instability recovered within
10 % of the simulator's truth; the flicker generator's Allan floor; errors for bad input."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from radical_rt.apps.cli import main
from radical_rt.contract.conventions import DEG, DEG_PER_HR
from radical_rt.contract.params import ParamTable
from replayer.synth.api import synthesize
from replayer.synth.scenario import load_scenario


def test_flicker_generator_floor():
    """Kasdin–Walter flicker with Q_d = B²: Allan floor (2 ln2/π)^½·B within the chi-square
    spread over 8 independent seeded records (4 % of the floor at 1σ for the mean)."""
    import allantools

    from replayer.synth.siru import flicker_bias

    rng = np.random.default_rng(20261202)
    floor = math.sqrt(2 * math.log(2) / math.pi)
    ratios = []
    for _ in range(8):
        x = flicker_bias(100_000, 1, 1.0, rng)[:, 0]
        _t, ad, _e, _n = allantools.oadev(x, rate=1.0, data_type="freq", taus=[10.0, 100.0])
        ratios.append(ad / floor)
    mean = np.mean(ratios, axis=0)
    assert np.all(np.abs(mean - 1.0) < 0.05), mean


@pytest.fixture(scope="module")
def static_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("allan")
    path = d / "static.mcap"
    # the built-in scenario (4 h inertial hold, its own seed); trackers and truth channels are
    # not needed here, and 100 reads per /siru message are faster to write and read (the SIRU
    # samples do not depend on either)
    synthesize({"base": "static", "trackers": {"st1": False, "st2": False},
                "output": {"truth": False}, "siru": {"batch": 100}}, path)
    out = d / "out"
    assert main(["allan", str(path), "-o", str(out)]) == 0
    return {"path": path, "out": out, "doc": json.loads((out / "allan.json").read_text())}


def test_static_recovers_arw_and_bias_instability(static_run):
    doc = static_run["doc"]
    siru = load_scenario("static").cfg["siru"]
    n_true = siru["arw_deg_sqrt_hr"] * DEG / 60.0  # rad/√s
    b_true = siru["bias_instability_deg_hr"] * DEG_PER_HR  # rad/s
    assert doc["truth_si"]["N"] == pytest.approx(n_true)
    assert doc["truth_si"]["B"] == pytest.approx(b_true)
    assert len(doc["gyros"]) == 4
    for g in doc["gyros"]:
        n, b = g["si"]["N"], g["si"]["B"]
        assert abs(n / n_true - 1) < 0.10, (g["name"], n / n_true)
        assert abs(b / b_true - 1) < 0.10, (g["name"], b / b_true)
        # paper units at the edge: deg/√hr and deg/hr
        assert g["paper"]["N"] == pytest.approx(n / (DEG / 60.0))
        assert g["paper"]["B"] == pytest.approx(b / DEG_PER_HR)
        assert g["si_sigma"]["N"] > 0 and g["si_sigma"]["B"] > 0
        tau, adev = np.array(g["tau"]), np.array(g["adev"])
        lo, hi = np.array(g["ci68_lo"]), np.array(g["ci68_hi"])
        assert np.all(lo <= adev) and np.all(adev <= hi)
        assert tau[0] == pytest.approx(0.01, rel=1e-3) and tau[-1] > 1000.0
    assert doc["missing_filled"] > 0 and doc["repeated_dropped"] > 0  # the clock's spates


def test_outputs_figure_and_param_table(static_run):
    from PIL import Image

    out = static_run["out"]
    img = np.asarray(Image.open(out / "allan.png").convert("RGB"))
    assert img.shape[0] > 500 and img.shape[1] > 800 and img.std() > 10
    table = ParamTable.from_toml(out / "allan_params.toml")  # radical process --config takes it
    worst = max(g["paper"]["N"] for g in static_run["doc"]["gyros"])
    assert table.active.arw_deg_sqrt_hr == pytest.approx(worst)
    assert "bias instability B [deg/hr]" in (out / "allan.md").read_text()


def test_refuses_moving_segment_and_bad_options(tmp_path, capsys):
    path = tmp_path / "slew.mcap"
    synthesize({"base": "2006216", "trackers": {"st1": False, "st2": False}}, path,
               duration=420.0)  # the first slew starts at 300 s
    assert main(["allan", str(path), "-o", str(tmp_path / "a")]) == 2
    assert "not static" in capsys.readouterr().err
    assert main(["allan", str(path), "--segment", "0:290", "-o", str(tmp_path / "b")]) == 0
    capsys.readouterr()
    assert main(["allan", str(path), "--segment", "300:100"]) == 2
    assert "T1 must be greater" in capsys.readouterr().err
    assert main(["allan", str(path), "--segment", "abc"]) == 2
    assert "T0:T1" in capsys.readouterr().err
    assert main(["allan", str(tmp_path / "none.mcap")]) == 2
    assert "cannot open" in capsys.readouterr().err
