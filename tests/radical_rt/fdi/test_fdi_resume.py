"""Issue 23, "resume that continues … FDI state": a checkpoint written while an FDI alarm is in
progress (its hypothesis bank running) and restored into a fresh processor continues the alarm:
the same isolation (gyro, alarm, isolation and snapshot times, margin), the same fault messages
after the resume point and the same final estimates as the uninterrupted run. Before (main at
fbe5c42): the checkpoint carried only the FDI outcome, the resumed monitor started over from
"monitoring" without history, snapshots or bank, and decided later (or not at all) from another
snapshot. Also: a damaged FDI field is refused with the field named, nothing changed."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest

from radical_rt.apps.batch import make_processor
from radical_rt.apps.node_setup import build_processors
from radical_rt.io import checkpoint as ckpt
from tests.support.streams import bias_step_messages

KEYS = ("gyro", "t_alarm", "t_isolated", "t_onset_est", "t_snapshot", "test", "llr_margin")


@pytest.fixture(scope="module")
def fault_archive(tmp_path_factory):
    """300 s from bus time 1000 s, gyro B bias step of 5 deg/hr at 120 s (tests/radical_rt/fdi/test_fdi.py)."""
    return bias_step_messages(tmp_path_factory.mktemp("fdi_resume"))


@pytest.fixture(scope="module")
def runs(fault_archive, tmp_path_factory):
    """The uninterrupted run, and a checkpoint taken in it mid-alarm (bank running, ≥ 3 tracker
    samples in, no decision yet), written to a file as the node does."""
    path = tmp_path_factory.mktemp("ck") / "mid.ckpt"
    sp, faults, cut = make_processor(), [], None
    for i, (topic, _ns, data) in enumerate(fault_archive):
        faults.extend(m for k, m in sp.feed(topic, data) if k == "fault")
        f = sp.engine.fdi
        if cut is None and f.state == "alarm" and f.bank is not None and f.bank.k >= 3:
            cut = i + 1
            ckpt.write(path, {"v": ckpt.capture(sp, "v")})
            n_before = len(faults)
    faults.extend(m for k, m in sp.end_stream(None) if k == "fault")
    assert cut is not None, "no alarm with a running bank in the scenario"
    return sp, faults, cut, n_before, path


def test_resume_mid_alarm_takes_the_same_decision(fault_archive, runs):
    ref, ref_faults, cut, n_before, path = runs
    assert ref.engine.fdi.isolations, "the uninterrupted run isolated nothing"
    sp = build_processors(["v"], resume=str(path))["v"]
    f = sp.engine.fdi
    assert f.state == "alarm" and f.bank is not None and f.bank.k >= 3  # the alarm goes on
    faults = []
    for topic, _ns, data in fault_archive[cut:]:
        faults.extend(m for k, m in sp.feed(topic, data) if k == "fault")
    faults.extend(m for k, m in sp.end_stream(None) if k == "fault")
    want, got = ref.engine.fdi.isolations, sp.engine.fdi.isolations
    assert [{k: r[k] for k in KEYS} for r in got] == [{k: r[k] for k in KEYS} for r in want]
    assert got[0]["gyro"] == 1
    # a resumed stream first re-announces its flags (the flags last published are not carried),
    # then publishes what the uninterrupted run published
    assert set(faults[0]["set"]) == {"PARITY_ALARM", "NOT_CONVERGED"}
    assert faults[1:] == ref_faults[n_before:]
    for k in ("xp", "d", "U", "q"):
        assert np.array_equal(getattr(sp.engine, k), getattr(ref.engine, k)), k


@pytest.mark.parametrize("field, value, needle", [
    (("gbuf", "f"), "unsorted", "time order"),
    (("trk",), "gap", "consecutive"),
    (("snaps",), "bad_d", "UD diagonal"),
    (("bank", "ll"), "nan", "finite"),
    (("bank",), "not_in_alarm", "only during an alarm"),
])
def test_damaged_fdi_state_is_refused(runs, field, value, needle):
    _ref, _f, _cut, _n, path = runs
    doc = ckpt.read(str(path))
    m = doc["vehicles"]["v"]["running"]["fdi"]["monitor"]
    if value == "unsorted":
        a = m["gbuf"]["f"]
        rows = np.frombuffer(a["data"], "<f8").reshape(a["shape"]).copy()
        rows[[0, -1]] = rows[[-1, 0]]
        a["data"] = rows.tobytes()
    elif value == "gap":
        a = m["trk"]["seq"]
        seq = np.frombuffer(a["data"], "<i8").copy()
        seq[1] += 1
        a["data"] = seq.tobytes()
    elif value == "bad_d":
        s = m["snaps"][0]["d"]
        d = np.frombuffer(s["data"], "<f8").copy()
        d[0] = 0.0
        s["data"] = d.tobytes()
    elif value == "nan":
        a = m["bank"]["ll"]
        ll = np.frombuffer(a["data"], "<f8").copy()
        ll[0] = np.nan
        a["data"] = ll.tobytes()
    elif value == "not_in_alarm":
        m["state"] = "monitoring"
    sp = make_processor()
    before = msgpack.packb(ckpt.capture(sp, "v"))
    with pytest.raises(ckpt.CheckpointError, match=needle):
        ckpt.restore(sp, doc["vehicles"]["v"])
    assert msgpack.packb(ckpt.capture(sp, "v")) == before  # nothing changed


def _as_schema_2(doc: dict) -> bytes:
    """The checkpoint ``doc`` (as ckpt.read returns it) in the format before /3: the FDI's
    tracker history as a list of rows [seq, t, tracker, q, n_stars], schema /2."""
    import hashlib

    doc = {k: v for k, v in doc.items() if k != "schema"}
    for st in doc["vehicles"].values():
        m = st["running"]["fdi"]["monitor"]
        col = {k: np.frombuffer(a["data"], a["dtype"]).reshape(a["shape"])
               for k, a in m["trk"].items()}
        m["trk"] = [[int(s), float(t), int(j), {"dtype": "<f8", "shape": [4], "data": q.tobytes()},
                     int(n)] for s, t, j, q, n in zip(col["seq"], col["t"], col["tracker"],
                                                      col["q"], col["n_stars"], strict=True)]
    body = msgpack.packb(doc, use_bin_type=True)
    return msgpack.packb({"schema": "radical.node_checkpoint/2",
                          "sha256": hashlib.sha256(body).hexdigest(), "body": body},
                         use_bin_type=True)


def test_schema_2_checkpoint_resumes_the_same(fault_archive, runs, tmp_path):
    """A checkpoint of the earlier format (schema /2, the tracker history as rows) restores the
    same tracker history as the current one (columns) and continues to the same isolation."""
    ref, _faults, cut, _n, path = runs
    old = tmp_path / "old.ckpt"
    old.write_bytes(_as_schema_2(ckpt.read(str(path))))
    sp_new = build_processors(["v"], resume=str(path))["v"]
    sp_old = build_processors(["v"], resume=str(old))["v"]
    trk_new, trk_old = sp_new.engine.fdi.trk, sp_old.engine.fdi.trk
    assert len(trk_old) == len(trk_new) > 3
    for k in (0, len(trk_new) // 2, -1):
        a, b = trk_old[k], trk_new[k]
        assert a[:3] == b[:3] and a[4] == b[4] and np.array_equal(a[3], b[3])
    for topic, _ns, data in fault_archive[cut:]:
        sp_old.feed(topic, data)
    sp_old.end_stream(None)
    got, want = sp_old.engine.fdi.isolations, ref.engine.fdi.isolations
    assert [{k: r[k] for k in KEYS} for r in got] == [{k: r[k] for k in KEYS} for r in want]
    assert np.array_equal(sp_old.engine.xp, ref.engine.xp)
