"""The message schemas of CONTRACT §3 (radical_rt.contract.schemas): names, meta-schemas, the
synthetic stream's messages, errors on bad messages, unknown topics and extensions."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from jsonschema import Draft202012Validator

from radical_rt.contract.schemas import SCHEMAS, schema_name, validate
from radical_rt.io.archive import (
    AUDIT_TOPICS,
    INPUT_TOPICS,
    OUTPUT_TOPICS,
    TRUTH_TOPICS,
)

ROOT = Path(__file__).resolve().parents[3]


# --------------------------------------------------------------------------------- schemas
def test_schema_names_and_meta_schemas():
    assert set(SCHEMAS) == set(INPUT_TOPICS + OUTPUT_TOPICS + TRUTH_TOPICS + AUDIT_TOPICS)
    assert schema_name("/siru") == "radical.siru"
    assert schema_name("/tlm/small") == "radical.tlm.small"
    assert schema_name("/truth/attitude") == "radical.truth.attitude"

    def described(node, where):
        for name, sub in node.get("properties", {}).items():
            assert sub.get("description"), f"{where}.{name} has no description"
            described(sub, f"{where}.{name}")

    for topic, s in SCHEMAS.items():
        Draft202012Validator.check_schema(s)
        assert s["title"] == schema_name(topic)
        assert "v" in s["required"] and s["properties"]["v"]["const"] == 1
        described(s, topic)
    assert set(SCHEMAS["/tlm/small"]["required"]) == {"v", "seq", "t", "q_body_from_inertial",
                                                      "flags", "mode"}


def test_stream_messages_validate(stream):
    for topic, m, _t in stream:
        if topic in SCHEMAS:
            assert validate(topic, m) == [], (topic, m)
    # numpy-valued messages (as a simulator builds them) validate too
    siru = {"v": 1, "t_bus": np.array([1.0, 1.01]), "tt": np.array([5, 10005], dtype=np.uint32),
            "dtheta": np.zeros((2, 4)), "status": np.zeros(2, dtype=np.int64)}
    assert validate("/siru", siru) == []


@pytest.mark.parametrize("topic, msg, pattern", [
    ("/st1", {"v": 1, "t_bus": 1.0, "n_stars": 9, "valid": True}, "'q' is a required"),
    ("/st1", {"v": 1, "t_bus": 1.0, "q": [0, 0, 1], "n_stars": 9, "valid": True}, "too short"),
    ("/st2", {"v": 1, "t_bus": 1.0, "q": [0, 0, 0, 1, 0], "n_stars": 9, "valid": True},
     "too long"),
    ("/st1", {"v": 2, "t_bus": 1.0, "q": [0, 0, 0, 1], "n_stars": 9, "valid": True},
     "1 was expected"),
    ("/siru", {"v": 1, "t_bus": [1.0], "tt": [1], "dtheta": [[0.0, 0.0, 0.0]], "status": [0]},
     "too short"),
    ("/siru", {"v": 1, "t_bus": [1.0, 1.01], "tt": [1], "dtheta": [[0.0] * 4], "status": [0]},
     "columns differ"),
    ("/siru", {"v": 1, "t_bus": [], "tt": [], "dtheta": [], "status": []}, "should be non-empty"),
    ("/siru", {"v": 1, "t_bus": [1.0], "tt": [1 << 32], "dtheta": [[0.0] * 4], "status": [0]},
     "maximum"),
    ("/tlm/small", {"v": 1, "seq": 0, "t": 1.0, "q_body_from_inertial": [0, 0, 0, 1],
                    "flags": 0, "mode": "sleeping"}, "is not one of"),
    ("/tlm/medium", {"v": 1, "seq": 0, "t": 1.0, "q_body_from_inertial": [0, 0, 0, 1],
                     "flags": 0, "mode": "init", "est": {"b": [0.0] * 4}}, "required"),
    ("/truth/params", {"v": 1, "t_bus": 0.0, "b": [0.0] * 4, "lam": [0.0] * 4, "mu": [0.0] * 4,
                       "du": [0.0] * 4, "dv": [0.0] * 4, "phi2": [0.0] * 4}, "too long"),
    ("/temp", {"v": 1, "t_bus": 1.0, "siru_C": "warm"}, "not of type 'number'"),
])
def test_bad_messages_give_errors(topic, msg, pattern):
    errs = validate(topic, msg)
    assert errs and any(re.search(pattern, e) for e in errs), errs
    assert all(e.startswith(topic + ": ") for e in errs)


def test_validate_unknown_topic_and_extensions():
    assert len(validate("/nope", {"v": 1})) == 1
    ok = {"v": 1, "seq": 3, "t": 1.0, "q_body_from_inertial": [0, 0, 0, 1], "flags": 0,
          "mode": "converged", "custom_field": [1, 2, 3]}
    assert validate("/tlm/small", ok) == []
    assert validate("/tlm/large", ok) == []  # configurable packets: only the small defaults required
    assert validate("/temp", {"v": 1, "t_bus": 2.0}) == []  # all temperatures optional
