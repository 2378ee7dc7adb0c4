"""The data fuzz harness (perf/fuzz_inputs.py) in short: 30,000 seeded bad payloads, among them
plausible-but-false ones, interleaved with a 20-s archive: no crash, hang, internal error or
state change (the full benchmark: 1,000,000 payloads, perf/README.md)."""

from __future__ import annotations

from perf.fuzz_inputs import KINDS, run
from tests.support.node import input_messages, make_archive


def test_fuzz_harness_short(tmp_path):
    msgs = input_messages(make_archive(tmp_path, "f20", seed=11, duration=20))
    res = run(msgs, 30_000, seed=2023, per_message=10.0, hang_s=2.0, log=lambda s: None)
    assert res["payloads"] == 30_000 and res["passes"] >= 3
    assert set(res["kinds"]) >= set(KINDS) - {"oversized"}
    assert (res["crashes"], res["hangs"], res["internal_errors"], res["state_changes"]) == \
        (0, 0, 0, 0), res
    assert res["reasons"].get("time_jump", 0) > 1000  # the plausible-but-false ones were there
