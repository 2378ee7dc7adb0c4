"""Rendezvous hashing (radical_rt.fleet.ownership): the same owner everywhere, balanced, and
only the vehicles of the worker that changed move."""

from __future__ import annotations

from collections import Counter

from radical_rt.fleet.ownership import assign, moves, owner, score

VEHICLES = [f"sat-{i:03d}" for i in range(600)]


def test_owner_is_deterministic_and_independent_of_order():
    ws = ["w-a", "w-b", "w-c"]
    assert assign(VEHICLES, ws) == assign(VEHICLES, list(reversed(ws)))
    assert owner("sat-001", []) is None
    assert score("w-a", "sat-001") != score("w-b", "sat-001")
    assert score("w-a", "sat-001") == score("w-a", "sat-001")


def test_load_is_balanced():
    counts = Counter(assign(VEHICLES, ["w-a", "w-b", "w-c"]).values())
    assert set(counts) == {"w-a", "w-b", "w-c"}
    assert all(150 <= n <= 250 for n in counts.values()), counts  # 200 ± 50 (σ ≈ 11.5)


def test_a_join_moves_only_vehicles_to_the_new_worker():
    m = moves(VEHICLES, ["w-a", "w-b", "w-c"], ["w-a", "w-b", "w-c", "w-d"])
    assert m and all(new == "w-d" for _, new in m.values())
    assert 100 <= len(m) <= 200, len(m)  # about a quarter of 600


def test_a_leave_moves_only_the_leavers_vehicles():
    before = assign(VEHICLES, ["w-a", "w-b", "w-c"])
    m = moves(VEHICLES, ["w-a", "w-b", "w-c"], ["w-a", "w-c"])
    assert set(m) == {v for v, w in before.items() if w == "w-b"}
    assert all(old == "w-b" and new in ("w-a", "w-c") for old, new in m.values())
