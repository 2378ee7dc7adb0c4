"""Golden outputs: every seeded case of tests/support/golden_cases.py reproduces its frozen record
(tests/golden/<case>.json) — outputs byte for byte (SHA-256 per topic), the summary, counters,
flags, mode and a trace of decoded messages. A deliberate numerical change regenerates the records
(``RADICAL_GOLDEN_UPDATE=1 python -m pytest tests/system/test_golden.py``) and commits the diff.
On a platform other than the recording one, numbers compare at tests.support.golden.RTOL."""

from __future__ import annotations

import os

import pytest

from tests.support import golden
from tests.support.golden_cases import CASES

UPDATE = os.environ.get("RADICAL_GOLDEN_UPDATE") == "1"


@pytest.mark.parametrize("feed", ["many", "one"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_golden_case(name, feed, monkeypatch):
    """feed: "many" — chunks through StreamProcessor.feed_many (the compiled block intake, as
    ``radical process``); "one" — message by message through feed (as the node): both must
    reproduce the same record."""
    monkeypatch.setitem(golden.FEED, "mode", feed)
    description, outputs, sp = golden.with_tmp(CASES[name])
    new = golden.record(name, description, outputs, sp)
    if UPDATE and feed == "one":
        golden.save(new)
    old = golden.load(name)
    exact = old["platform"] == golden.platform_id()
    diffs = golden.differences(new, old, exact=exact)
    assert not diffs, (f"{name} differs from tests/golden/{name}.json "
                       f"({'exact' if exact else f'rtol {golden.RTOL}'}):\n" + "\n".join(diffs))
    assert new["outputs"]["n"] > 100  # the case produced a real run


def test_differences_sees_a_changed_bit():
    """The comparison itself: one ulp in a trace float, a count, a missing key."""
    old = {"a": [1.0, 2.0], "b": {"c": 3}, "platform": {"cpu": "x"}}
    assert golden.differences({"a": [1.0, 2.0], "b": {"c": 3}, "platform": {}}, old) == []
    assert golden.differences({"a": [1.0, 2.0000000000000004], "b": {"c": 3}}, old, exact=True)
    assert not golden.differences({"a": [1.0, 2.0000000000000004], "b": {"c": 3}}, old,
                                  exact=False)
    assert golden.differences({"a": [1.0, 2.0], "b": {"c": 4}}, old, exact=False)
    assert golden.differences({"a": [1.0], "b": {}}, old)
