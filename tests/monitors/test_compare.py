"""monitors.compare (issue #21 item 6): mode and convergence in the table; a summary made from
another archive is refused (or, with --force, loudly warned)."""

from __future__ import annotations

import json

import pytest

from monitors import compare
from radical_rt.apps.batch import process
from replayer.synth.api import synthesize


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("cmp")
    out = {}
    for name, base, seed in (("a", "2005301", 5), ("b", "2006216", 6)):
        arc = d / f"{name}.mcap"
        synthesize({"base": base}, arc, seed=seed, duration=20.0)
        summ = d / f"{name}.json"
        process([str(arc)], None, str(summ))
        out[name] = (arc, summ)
    return out


def test_mode_and_convergence_printed(runs, capsys):
    arc, summ = runs["a"]
    assert compare.main([str(arc), str(summ), "--labels", "A"]) == 0
    out = capsys.readouterr().out
    mode = json.loads(summ.read_text())["mode"]
    assert f"| mode | | {mode} |" in out
    assert "| converged | | NO |" in out or "| converged | | yes |" in out


def test_foreign_summary_refused_or_warned(runs, capsys):
    arc, _ = runs["a"]
    _, foreign = runs["b"]
    assert compare.main([str(arc), str(foreign)]) == 2
    err = capsys.readouterr().err
    assert "does not belong to" in err and "--force" in err
    assert compare.main([str(arc), str(foreign), "--force"]) == 0
    assert "WARNING" in capsys.readouterr().err


def test_provenance_by_truth_and_by_source(runs):
    arc_a, summ_a = runs["a"]
    s = json.loads(summ_a.read_text())
    truth = compare.load_truth(arc_a)
    assert compare.provenance_problem(arc_a, truth, s) == ""
    no_streams = {k: v for k, v in s.items() if k != "streams"}
    changed = json.loads(json.dumps(no_streams))
    changed["truth"]["b"][0] += 0.01
    assert "truth" in compare.provenance_problem(arc_a, truth, changed)
    no_truth = {k: v for k, v in s.items() if k != "truth"}
    no_truth["streams"][0]["source"] = "/x/other.mcap"
    assert "other.mcap" in compare.provenance_problem(arc_a, truth, no_truth)
    bare = {k: v for k, v in s.items() if k not in ("truth", "streams")}
    assert compare.provenance_problem(arc_a, truth, bare) == ""  # contract-only: no evidence
