"""Scenarios: built-ins against the paper's tables, TOML loading and its error messages,
--print-default round trip, the CLI's exit codes, and the simulator's independence from the filter."""

from __future__ import annotations

import argparse
import ast
import json
from pathlib import Path

import numpy as np
import pytest

from radical_rt.contract.conventions import SI_PER_PAPER_UNIT
from replayer.synth import BUILTINS, ScenarioError, cli, load_scenario
from replayer.synth.scenario import GROUPS, print_default

SHARED_TABLES = Path("/work/shared/data/messenger_tables.json")
PKG_TABLES = Path(__file__).parents[3] / "replayer" / "synth" / "messenger_tables.json"
SYNTH_DIR = Path(__file__).parents[3] / "replayer" / "synth"


def tables():
    return json.loads((SHARED_TABLES if SHARED_TABLES.exists() else PKG_TABLES).read_text())


@pytest.mark.skipif(not SHARED_TABLES.exists(), reason="shared tables not mounted")
def test_packaged_tables_are_the_shared_copy():
    assert json.loads(PKG_TABLES.read_text()) == json.loads(SHARED_TABLES.read_text())


@pytest.mark.parametrize("name", ["2005300", "2005301", "2006216"])
def test_builtin_truth_is_the_paper_row_in_si(name):
    sc = load_scenario(name)
    row = tables()["estimates"][name]
    for key, (group, n) in GROUPS.items():
        assert sc.truth[group].shape == (n,)
        assert np.allclose(sc.truth[group], np.array(row[key]) * SI_PER_PAPER_UNIT[group], rtol=1e-15)
    assert sc.cfg["duration_s"] == 7200.0 and sc.cfg["maneuver"]["profile"] == "messenger"


@pytest.mark.parametrize("name", ["original", "alternate"])
def test_uniform_truth_within_table1_and_seeded(name):
    a, b, c = load_scenario(name), load_scenario(name), load_scenario(name, seed=99)
    lims = tables()["table1_initial_uniform_L"]
    for key, (group, _) in GROUPS.items():
        paper = a.truth[group] / SI_PER_PAPER_UNIT[group]
        assert np.all(np.abs(paper) <= lims[key])
        assert np.array_equal(a.truth[group], b.truth[group])
        assert not np.array_equal(a.truth[group], c.truth[group])


def test_toml_base_and_overrides(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text('base = "2006216"\nname = "mine"\nduration_s = 30\n[siru]\neps_ppm = -25\n'
                 '[truth]\nb_deg_hr = [1, 2, 3, 4]\n'
                 '[[faults]]\nkind = "gap"\nstart_s = 5.0\nend_s = 6.0\n')
    sc = load_scenario(p)
    assert sc.name == "mine" and sc.cfg["duration_s"] == 30.0 and sc.cfg["siru"]["eps_ppm"] == -25.0
    assert sc.cfg["siru"]["period_s"] == 0.01  # inherited
    assert np.allclose(sc.truth["b"], np.array([1, 2, 3, 4]) * SI_PER_PAPER_UNIT["b"])
    assert np.allclose(sc.truth["lam"], np.array([326.4, -261.4, 602.8, 358.7]) * 1e-6)
    assert sc.cfg["faults"] == [{"kind": "gap", "start_s": 5.0, "end_s": 6.0}]


BAD = [
    ('[siru]\neps_pmm = 3\n', "unknown scenario key 'siru.eps_pmm'", "eps_ppm"),
    ('durration_s = 3\n', "unknown scenario key 'durration_s'", "duration_s"),
    ('[siru]\neps_ppm = "x"\n', "'siru.eps_ppm': expected float", None),
    ('[truth]\nphi2_arcsec = [1, 2]\n', "'truth.phi2_arcsec': expected a list of 3", None),
    ('[trackers]\nst1 = 1\n', "'trackers.st1': expected bool", None),
    ('seed = 1.5\n', "'seed': expected int", None),
    ('siru = 3\n', "'siru': expected a table", None),
    ('[[faults]]\nkind = "meteor"\n', "'faults[0].kind': expected one of", "bias_step"),
    ('[[faults]]\nkind = "zero"\nstart_s = 1.0\n', "missing required key(s) gyro", None),
    ('[[faults]]\nkind = "zero"\ngyro = 9\nstart_s = 1.0\n', "'faults[0].gyro'", None),
    ('[[faults]]\nkind = "zero"\ngyro = 1\nstart_s = 1.0\nmagnitude = 2\n',
     "unknown scenario key 'faults[0].magnitude'", "end_s"),
    ('[[faults]]\nkind = "gap"\nstart_s = 5.0\nend_s = 4.0\n', "'faults[0].end_s'", None),
    ('[siru]\nphase_s = 0.02\n', "'siru.phase_s': must be in [0, period_s)", None),
    ('[trackers]\nrate_hz = 3.0\n', "'trackers.rate_hz': period must be a whole number", None),
    ('duration_s = -1\n', "'duration_s': must be > 0", None),
    ('vehicle = "My Craft"\n', "'vehicle'", None),
    ('[maneuver]\nprofile = "loop"\n', "'maneuver.profile'", "messenger"),
    ('[[maneuver.moves]]\naxis = "w"\nangle_deg = 3\n', "'maneuver.moves[0].axis'", None),
    ('[truth]\nsource = "2099001"\n', "'truth.source'", "uniform"),
    ('base = "nope"\n', "unknown built-in scenario 'nope'", "2006216"),
    ('[siru\n', "invalid TOML", None),
]


@pytest.mark.parametrize("text,message,listed", BAD, ids=[b[1][:40] for b in BAD])
def test_toml_errors_are_clear(tmp_path, text, message, listed):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(ScenarioError) as exc:
        load_scenario(p)
    msg = str(exc.value)
    assert message in msg and "\n" not in msg
    if listed:
        assert listed in msg


@pytest.mark.parametrize("name", sorted(BUILTINS))
def test_print_default_round_trips(tmp_path, name):
    text = print_default(name)
    p = tmp_path / "d.toml"
    p.write_text(text)
    a, b = load_scenario(name), load_scenario(p)
    assert a.cfg == b.cfg
    for g in a.truth:
        assert np.array_equal(a.truth[g], b.truth[g])


def _cli(argv):
    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    return cli.run(parser.parse_args(argv))


def test_cli_exit_codes(tmp_path, capsys):
    out = tmp_path / "o.mcap"
    assert _cli(["2006216", "-o", str(out), "--duration", "3", "--seed", "5", "--quiet"]) == 0
    assert out.exists()
    assert _cli(["no-such-scenario", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("radical synth: error: scenario 'no-such-scenario'")
    bad = tmp_path / "b.toml"
    bad.write_text('[siru]\nbogus = 1\n')
    assert _cli([str(bad), "-o", str(out)]) == 2
    assert "bogus" in capsys.readouterr().err
    assert _cli(["2006216"]) == 2
    assert _cli(["--print-default", "alternate"]) == 0
    printed = capsys.readouterr().out
    assert 'name = "alternate"' in printed and "[[faults]]" not in printed


FORBIDDEN = ("radical_rt.kernels.model", "radical_rt.kernels.tracker_model", "radical_rt.kernels.parametrization",
             "radical_rt.engine.filter", "radical_rt.contract.params", "radical_rt.kernels.ud",
             "radical_rt.kernels.propagate", "radical_rt.clock.siru_clock", "radical_rt.fdi.monitor", "radical_rt.apps.batch")


def test_simulator_does_not_import_the_filter():
    # radical_rt.io.outpaths: the command line's output-path policy (synth -o); radical_rt.io.archive:
    # the CONTRACT's MCAP layer the simulator writes with; no filter code in either
    allowed = {"radical_rt", "radical_rt.contract.conventions", "radical_rt.contract.geometry",
               "radical_rt.kernels.rotation", "radical_rt.io.outpaths", "radical_rt.io.archive"}
    for path in SYNTH_DIR.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            for n in names:
                if n.startswith("radical_rt"):
                    assert n in allowed and not n.startswith(FORBIDDEN), f"{path.name}: {n}"
