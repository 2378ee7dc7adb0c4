"""`radical export --foxglove`: read back with the official TypeScript MCAP reader (@mcap/core via
node, tests/js/read_mcap.mjs), every message validated against its channel schema and every
foxglove.FrameTransform / foxglove.Log against the schemas Foxglove publishes (@foxglove/schemas).

Needs node and `npm ci --prefix tests/js` (the Makefile's `test` target runs it). Missing, the
test fails with the command to run; it never skips.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from radical_rt.apps.batch import process
from radical_rt.apps.cli import main
from radical_rt.contract.conventions import ARCSEC, DEG_PER_HR
from radical_rt.io.archive import ArchiveReader
from replayer.synth.api import synthesize

JS = Path(__file__).parents[1] / "js"


def node_read(path: Path) -> dict:
    node = shutil.which("node")
    assert node, "node is required: apt-get install nodejs (node >= 18)"
    assert (JS / "node_modules" / "@mcap" / "core").exists(), (
        "JS readers missing: run `npm ci --prefix tests/js` (make jsdeps)")
    res = subprocess.run([node, str(JS / "read_mcap.mjs"), str(path)], capture_output=True,
                         text=True, timeout=120)
    assert res.returncode == 0, res.stderr[-3000:]
    return json.loads(res.stdout)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    d = tmp_path_factory.mktemp("fox")
    sim, out = d / "sim.mcap", d / "out.mcap"
    synthesize({"base": "2006216", "t_start_s": 500.0}, sim, seed=11, duration=90.0)
    process([str(sim)], str(out))
    fox_in, fox_out = d / "sim.fox.mcap", d / "out.fox.mcap"
    assert main(["export", "--foxglove", str(sim), "-o", str(fox_in), "--quiet"]) == 0
    assert main(["export", "--foxglove", str(out), "-o", str(fox_out), "--quiet"]) == 0
    return {"sim": sim, "out": out, "fox_in": fox_in, "fox_out": fox_out,
            "read_in": node_read(fox_in), "read_out": node_read(fox_out)}


def _counts(path: Path) -> dict[str, int]:
    with ArchiveReader(path) as r:
        return {t: n for t, n in r.message_counts.items() if n}


def test_every_channel_json_and_valid(exported):
    for src, key in (("sim", "read_in"), ("out", "read_out")):
        rd = exported[key]
        assert rd["schemaErrors"] == [], rd["schemaErrors"]
        assert rd["messageErrors"] == [], rd["messageErrors"]
        assert rd["officialErrors"] == [], rd["officialErrors"]
        assert rd["outOfOrder"] == 0
        for topic, ch in rd["channels"].items():
            assert ch["messageEncoding"] == "json", topic
            assert ch["schemaEncoding"] == "jsonschema", topic
        # every source message is there, same count, same topic
        for topic, n in _counts(exported[src]).items():
            assert rd["channels"][topic]["count"] == n, topic
        assert {m["name"] for m in rd["metadata"]} >= {"radical.scenario", "radical.export"}


def test_frame_transforms(exported):
    out, sim = exported["read_out"], exported["read_in"]
    counts = _counts(exported["out"])
    ch = out["channels"]
    for topic in ("/tf/body", "/tf/st1", "/tf/st2"):
        assert ch[topic]["schemaName"] == "foxglove.FrameTransform"
        assert ch[topic]["officialChecked"] == ch[topic]["count"] > 0
    assert ch["/tf/body"]["count"] == counts["/tlm/small"]  # attitude at the fastest packet
    assert ch["/tf/st2"]["count"] == counts["/tlm/large"]
    assert out["frames"] == {"inertial->body": counts["/tlm/small"],
                             "body->st1": counts["/tlm/large"], "body->st2": counts["/tlm/large"],
                             "body->st2_truth": counts["/truth/params"]}
    sim_counts = _counts(exported["sim"])
    assert sim["frames"] == {"inertial->body_truth": sim_counts["/truth/attitude"],
                             "body->st2_truth": sim_counts["/truth/params"]}

    def rot(m):
        r = m["msg"]["rotation"]
        return Rotation.from_quat([r["x"], r["y"], r["z"], r["w"]])

    # st1: the child's boresight (+z in st1) is body −z (CONTRACT §1.4; rotation = child → parent)
    r1 = rot(out["lastMessages"]["/tf/st1"])
    assert np.allclose(r1.apply([0, 0, 1.0]), [0, 0, -1.0], atol=1e-12)
    assert np.allclose(r1.apply([1.0, 0, 0]), [1.0, 0, 0], atol=1e-12)
    # st2: R_st2_from_body = R_nom @ R(phi2)^T with the last estimate of phi2
    with ArchiveReader(exported["out"]) as r:
        large = [m for _t, _ns, m in r.iter_messages("/tlm/large")]
        small = [(ns, m) for _t, ns, m in r.iter_messages("/tlm/small")]
        truth = [(ns, m) for _t, ns, m in ArchiveReader(exported["sim"]).iter_messages(
            "/truth/attitude")]
    nom = np.array([[0, -1.0, 0], [-1.0, 0, 0], [0, 0, -1.0]])
    r_st2_from_body = nom @ Rotation.from_rotvec(large[-1]["est"]["phi2"]).as_matrix().T
    assert np.allclose(rot(out["lastMessages"]["/tf/st2"]).as_matrix(), r_st2_from_body.T,
                       atol=1e-12)
    # st2_truth: the same formula with the true phi2; st2 and st2_truth differ by the error
    with ArchiveReader(exported["out"]) as r:
        tp = [m for _t, _ns, m in r.iter_messages("/truth/params")][-1]
    r_true = nom @ Rotation.from_rotvec(tp["phi2"]).as_matrix().T
    st2t = rot(out["lastMessages"]["/tf/st2_truth"])
    assert np.allclose(st2t.as_matrix(), r_true.T, atol=1e-12)
    err = np.array(large[-1]["est"]["phi2"]) - np.array(tp["phi2"])
    assert (st2t.inv() * rot(out["lastMessages"]["/tf/st2"])).magnitude() == pytest.approx(
        np.linalg.norm(err), rel=1e-3, abs=1e-9)
    # body: rotation = q_inertial_from_body; the estimate lies within 30″ of the truth
    last_ns, last = small[-1]
    fb = out["lastMessages"]["/tf/body"]
    assert int(fb["logTime"]) == last_ns
    assert fb["msg"]["timestamp"] == {"sec": last_ns // 10**9, "nsec": last_ns % 10**9}
    r_body = Rotation.from_quat(last["q_body_from_inertial"])
    assert (rot(fb) * r_body).magnitude() < 1e-12
    t_ns = np.array([ns for ns, _m in truth])
    i = int(np.argmin(np.abs(t_ns - last_ns)))
    tb = rot(sim["lastMessages"]["/tf/body_truth"]) if i == len(truth) - 1 else None
    r_truth = Rotation.from_quat(truth[i][1]["q_body_from_inertial"])
    if tb is not None:
        assert (tb * r_truth).magnitude() < 1e-12
    dt = abs(t_ns[i] - last_ns) * 1e-9
    assert dt < 0.2
    moved = np.linalg.norm(truth[i][1]["omega_body"]) * dt  # the truth sample is dt away
    assert (rot(fb) * r_truth).magnitude() < 30 * ARCSEC + moved


def test_fault_log_and_paper_units(exported):
    out = exported["read_out"]
    with ArchiveReader(exported["out"]) as r:
        faults = [m for _t, _ns, m in r.iter_messages("/fault")]
        large = [m for _t, _ns, m in r.iter_messages("/tlm/large")]
    assert faults, "the run has at least the initial NOT_CONVERGED fault message"
    assert out["channels"]["/log/faults"]["count"] == len(faults)
    assert out["channels"]["/log/faults"]["schemaName"] == "foxglove.Log"
    log = out["lastMessages"]["/log/faults"]["msg"]
    for name in faults[-1]["set"]:
        assert name in log["message"]
    paper = out["lastMessages"]["/paper/calibration"]["msg"]
    assert paper["est"]["b"] == pytest.approx(np.array(large[-1]["est"]["b"]) / DEG_PER_HR,
                                              rel=1e-12)
    assert paper["sigma"]["du"] == pytest.approx(np.array(large[-1]["sigma"]["du"]) / ARCSEC,
                                                 rel=1e-12)
    assert paper["est"]["lam"] == pytest.approx(np.array(large[-1]["est"]["lam"]) * 1e6,
                                                rel=1e-12)
    assert set(paper["truth"]) == {"b", "lam", "mu", "du", "dv", "phi2"}


def test_siru_columns_and_units_in_schemas(exported):
    rd = exported["read_in"]
    first = rd["firstMessages"]["/siru"]["msg"]
    with ArchiveReader(exported["sim"]) as r:
        src = next(m for _t, _ns, m in r.iter_messages("/siru"))
    assert list(first["dtheta"]) == ["A", "B", "C", "D"]
    for i, g in enumerate("ABCD"):
        assert first["dtheta"][g] == [row[i] for row in src["dtheta"]]
    assert first["tt"] == src["tt"] and first["t_bus"] == src["t_bus"]
    from mcap.reader import make_reader

    with open(exported["fox_out"], "rb") as f:
        schemas = {s.name: json.loads(s.data) for s in make_reader(f).get_summary().schemas.values()}
    large = schemas["radical.tlm.large"]
    assert "(rad/s)" in large["properties"]["est"]["properties"]["b"]["description"]
    paper = schemas["radical.paper.calibration"]
    assert "deg/hr" in paper["properties"]["est"]["properties"]["b"]["description"]
    diag = schemas["radical.diag"]
    assert diag["properties"]["clock"]["properties"]["freq_offset_ppm"]["description"].endswith(
        "(ppm)")


def test_export_errors(tmp_path, capsys):
    assert main(["export", "--foxglove", str(tmp_path / "missing.mcap"), "-o",
                 str(tmp_path / "x.mcap")]) == 2
    assert "no such file" in capsys.readouterr().err
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file")
    assert main(["export", "--foxglove", str(bad), "-o", str(tmp_path / "x.mcap")]) == 2
    assert "not an MCAP archive" in capsys.readouterr().err
    assert main(["export", str(bad), "-o", str(tmp_path / "x.mcap")]) == 2
    assert "--foxglove" in capsys.readouterr().err


def test_json_and_schema_rules():
    """The Foxglove/Lichtblick subset: no arrays of arrays, one type per field, object schemas."""
    from monitors.fox_convert import jsonable, siru_columns
    from monitors.fox_schema import SchemaBuilder, check_foxglove_subset

    m = jsonable({"a": float("nan"), "b": [1.0, float("inf"), 2.0], 3: {"x": None, "y": 1},
                  "c": (1, 2), "d": np.float64(2.5), "e": [np.int64(4)]})
    assert m == {"b": [1.0, None, 2.0], "3": {"y": 1}, "c": [1, 2], "d": 2.5, "e": [4]}
    assert siru_columns({"dtheta": [[1.0, 2.0], [3.0, 4.0]]})["dtheta"] == {"A": [1.0, 3.0],
                                                                              "B": [2.0, 4.0]}
    b = SchemaBuilder("t", "test")
    b.observe({"n": 1, "rate_ppm": [1, 2], "m": {"k_s": True}})
    b.observe({"n": 1.5, "rate_ppm": [], "m": {"k_s": False}, "extra": "x"})
    s = b.schema()
    assert s["properties"]["n"]["type"] == "number"  # int and float merged
    assert s["properties"]["rate_ppm"]["items"]["type"] == "integer"
    assert "(ppm)" in s["properties"]["rate_ppm"]["description"]
    assert s["properties"]["extra"]["type"] == "string"
    assert check_foxglove_subset(s) == []
    bad = {"type": "object", "properties": {"v": {"const": 1},
                                            "a": {"type": "array", "items": {"type": "array"}}}}
    assert len(check_foxglove_subset(bad)) == 2
