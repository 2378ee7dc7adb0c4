"""The SIRU clock says, in state and words, why it is not locked (summary, diag, node log)."""

from __future__ import annotations

import logging

import numpy as np

from radical_rt.apps.batch import clock_line
from radical_rt.apps.node_clock import ClockNotice
from radical_rt.clock.siru_clock import SiruClock

T = 0.01


def _reads(n: int, eps_ppm: float, seed: int, jitter: float = 20e-6):
    """n bus reads at tick-tagged 100 Hz of a SIRU with offset ε (tt, tags)."""
    rng = np.random.default_rng(seed)
    t_k = 0.0043 + np.arange(n + 10) * T * (1 + eps_ppm * 1e-6)
    tag = np.arange(1, n + 1) * T
    k = np.searchsorted(t_k, tag - 3e-4 - rng.normal(0, jitter, n), side="right") - 1
    return tag, 10000 * k


def _push(clock, tag, tt):
    clock.push(tag, tt, np.zeros((tag.size, 4)), np.zeros(tag.size, np.int64))


def test_states_from_acquiring_to_locked():
    tag, tt = _reads(80000, 100.0, seed=1)  # wraps every 100 s
    clock = SiruClock()
    _push(clock, tag[:3000], tt[:3000])
    state, note = clock.status()
    assert state == "acquiring" and "no sawtooth wrap" in note and not clock.locked
    n = 1
    while clock.counters["crossings"] == 0:
        _push(clock, tag[n * 3000:(n + 1) * 3000], tt[n * 3000:(n + 1) * 3000])
        n += 1
    assert clock.status()[0] in ("one_wrap", "locked")
    _push(clock, tag[n * 3000:n * 3000 + 1900], tt[n * 3000:n * 3000 + 1900])
    assert clock.status()[0] == "one_wrap"  # σ grows without a second wrap
    _push(clock, tag[n * 3000 + 1900:], tt[n * 3000 + 1900:])
    tel = clock.telemetry()
    assert tel["state"] == "locked" and tel["note"] == "" and tel["t_first_lock_s"] > 100.0
    assert abs(tel["freq_offset_ppm"] - 100.0) < 0.05


def test_never_locked_is_said_in_the_summary_line():
    tag, tt = _reads(20000, 5.0, seed=2)  # 200 s at 5 ppm: no wrap
    clock = SiruClock()
    _push(clock, tag, tt)
    from radical_rt.apps.batch import clock_summary
    line = clock_line(clock_summary(clock))
    assert "NEVER LOCKED" in line and "no sawtooth wrap" in line


def test_node_notice_says_it_once(caplog):
    notice = ClockNotice("v1", warn_after_s=100.0)
    caplog.set_level(logging.INFO, logger="radical.node")
    acq = {"state": "acquiring", "note": "no sawtooth wrap in N s"}
    for t in range(0, 400):
        notice.seen(acq, float(t))
    warn = [r for r in caplog.records if "not locked after" in r.message]
    assert len(warn) == 1 and "no sawtooth wrap" in warn[0].message
    notice.seen({"state": "locked", "note": "", "freq_offset_ppm": 12.0}, 401.0)
    notice.seen({"state": "unlocked", "note": "σ grew"}, 402.0)
    msgs = [r.message for r in caplog.records]
    assert any("locked (ε +12.000 ppm)" in m for m in msgs)
    assert any("lost its lock: σ grew" in m for m in msgs)
