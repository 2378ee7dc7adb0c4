"""The command and checkpoint fuzz benchmark (perf/fuzz_commands.py) in a shortened form: 400
seeded commands (valid-but-extreme and invalid) and 150 damaged checkpoints, in watched worker
processes. Crashes, hangs, internal errors, state changes by refused inputs, invalid inputs
accepted and NUMERIC stuck after a cold start must all be 0."""

from __future__ import annotations

from perf.fuzz_commands import run_kind

BAD = ("crashes", "hangs", "internal", "state_change", "accepted_invalid", "numeric_stuck")


def test_command_fuzz_short(tmp_path):
    r = run_kind("commands", 400, seed=2323, feed=4, work=str(tmp_path))
    c = r["counts"]
    assert c["cases"] == 400 and c["valid"] > 100 and c["invalid"] > 100, c
    assert {k: c.get(k, 0) for k in BAD} == dict.fromkeys(BAD, 0), r["examples"]


def test_checkpoint_fuzz_short(tmp_path):
    r = run_kind("checkpoints", 150, seed=2323, feed=4, work=str(tmp_path))
    c = r["counts"]
    assert c["cases"] == 150 and c["refused"] > 50, c
    assert c["one_line"] == c["refused"]
    assert {k: c.get(k, 0) for k in BAD} == dict.fromkeys(BAD, 0), r["examples"]
