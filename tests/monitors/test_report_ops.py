"""`radical report` operations view: streams apart, attitude error, failed gyro, report.html."""

from __future__ import annotations

import re

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from monitors.report_data import ArchiveData  # noqa: E402
from monitors.report_ops import attitude_error, common_axis, load_ops, split_streams  # noqa: E402
from monitors.report_tables import table_markdown  # noqa: E402
from radical_rt.apps.batch import process  # noqa: E402
from radical_rt.apps.cli import main  # noqa: E402
from replayer.synth.api import synthesize  # noqa: E402


@pytest.fixture(scope="module")
def two_streams(tmp_path_factory):
    d = tmp_path_factory.mktemp("ops")
    a, b = d / "a.mcap", d / "b.mcap"
    synthesize({"base": "2005301"}, a, seed=1, duration=90.0)  # both start at t = 0
    synthesize({"base": "2006216"}, b, seed=2, duration=90.0)
    p = d / "p.mcap"
    process([str(a), str(b)], str(p))
    return p


def test_split_by_backwards_step_and_field():
    t = np.array([0.0, 1.0, 2.0, 0.5, 1.5])
    assert split_streams(t, [None] * 5).tolist() == [0, 0, 0, 1, 1]
    assert split_streams(t, [0, 0, 1, 1, 1]).tolist() == [0, 0, 1, 1, 1]
    x, bounds = common_axis(t * 60, split_streams(t, [None] * 5))
    assert np.all(np.diff(x) > 0) and [k for _x, k in bounds] == [0, 1]


def test_two_overlapping_streams_drawn_apart(two_streams, tmp_path):
    d = load_ops(str(two_streams), "p")
    assert len(d.boundaries) == 2  # the bus times overlap, the streams do not
    assert np.all(np.diff(d.x) > 0), "figure x must increase monotonically (no zig-zag)"
    assert d.x[d.stream == 1].min() > d.x[d.stream == 0].max()
    out = tmp_path / "rep"
    assert main(["report", str(two_streams), "-o", str(out)]) == 0
    assert (out / "ops_p.png").stat().st_size > 20000
    page = (out / "report.html").read_text()
    assert "warm start" in page and "cold start" in page
    assert not re.search(r"<script[^>]+src=[\"']https?:", page)
    assert "Bokeh" in page and "<script" in page


def test_attitude_error_against_truth():
    from scipy.spatial.transform import Rotation as R

    qt = R.from_euler("z", np.linspace(0, 1, 5)[:, None]).as_quat()
    arcsec = np.pi / 180 / 3600
    qe = (R.from_rotvec([10 * arcsec, 0, 0]) * R.from_quat(qt)).as_quat()
    t = np.arange(5.0)
    err = attitude_error(qe, t, t, qt)
    assert err[:, 0] == pytest.approx(10.0, rel=1e-3) and np.abs(err[:, 1:]).max() < 1e-6


def test_failed_gyro_marked(two_streams):
    from monitors.report_data import load_archive

    d: ArchiveData = load_archive(str(two_streams), "x")
    d.last = dict(d.last, flags=1 << 2)  # GYRO_B_FAILED
    md = table_markdown([d], "b")
    row = next(line for line in md.splitlines() if line.startswith("| x |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[4].startswith("FAILED") and not cells[2].startswith("FAILED")


# ------------------------------------------------------------------- report.html (Bokeh JSON)
def _bokeh_models(page: str) -> list[dict]:
    """Every serialized model of the page's embedded Bokeh document (type "object")."""
    import json

    blobs = re.findall(r'<script type="application/json" id="[^"]+">\s*(.*?)\s*</script>', page,
                       re.S)
    assert len(blobs) == 1, "report.html must embed exactly one Bokeh document"
    out: list[dict] = []

    def walk(o):
        if isinstance(o, dict):
            if o.get("type") == "object" and "name" in o:
                out.append(o)
            for v in o.values():
                walk(v)
        elif isinstance(o, list):
            for v in o:
                walk(v)

    walk(json.loads(blobs[0]))
    return out


def _attr(m: dict, key: str):
    return (m.get("attributes") or {}).get(key)


def _figures(models: list[dict]) -> dict[str, dict]:
    return {_attr(m, "name"): m for m in models
            if m["name"] == "Figure" and isinstance(_attr(m, "name"), str)}


@pytest.fixture(scope="module")
def page(two_streams, tmp_path_factory):
    out = tmp_path_factory.mktemp("html")
    assert main(["report", str(two_streams), "-o", str(out)]) == 0
    return (out / "report.html").read_text()


def test_html_has_nis_flags_euler_and_marker_panels(page):
    from monitors.report_ops_html import EULER_TITLE

    models = _bokeh_models(page)
    figs = _figures(models)
    for panel in ("NIS per tracker with chi-square 95 % bounds", "flag timeline", EULER_TITLE,
                  "attitude quaternion q_body_from_inertial (scalar last)"):
        assert f"ops:p:{panel}" in figs, (panel, sorted(figs))
    names = [_attr(m, "name") for m in models]
    assert "nis:st1" in names and "nis:st2" in names
    # stream boundaries and fault messages as named vertical markers on every panel
    n_bound = sum(1 for m in models if _attr(m, "name") == "marker:boundary"
                  and m["name"] == "GlyphRenderer")
    assert n_bound == len(figs)
    assert any(_attr(m, "name") in ("marker:fault", "marker:isolation", "marker:clear")
               for m in models), "the archive has fault messages: they must be marked"
    legends = {_attr(i, "label").get("value") for m in models if m["name"] == "Legend"
               for i in _attr(m, "items") or [] if isinstance(_attr(i, "label"), dict)}
    assert "stream boundary" in legends
    # flag timeline: one categorical row per flag bit set, named by radical_rt.contract.flags.Flag
    flag_fig = figs["ops:p:flag timeline"]
    rows = _attr(_attr(flag_fig, "y_range"), "factors") if isinstance(
        _attr(flag_fig, "y_range"), dict) else None
    from radical_rt.contract.flags import Flag

    assert rows and set(rows) <= {f.name for f in Flag}
    assert any(n.startswith("flag:") for n in names if isinstance(n, str))


def test_html_chi2_bounds_dof3(page):
    models = _bokeh_models(page)
    span = {_attr(m, "name"): _attr(m, "location") for m in models if m["name"] == "Span"
            and str(_attr(m, "name")).startswith("chi2:")}
    # scipy.stats.chi2.ppf(0.025 / 0.975, 3)
    assert span["chi2:st1:lo"] == pytest.approx(0.215795, abs=1e-5)
    assert span["chi2:st1:hi"] == pytest.approx(9.348404, abs=1e-5)
    assert span["chi2:st2:hi"] == pytest.approx(9.348404, abs=1e-5)


def test_euler_321_pinned():
    from scipy.spatial.transform import Rotation as R

    from monitors.view import euler_321

    yaw, pitch, roll = 30.0, -20.0, 10.0
    # q = q_z(yaw) ⊗ q_y(pitch) ⊗ q_x(roll), written out (scalar last), independent of scipy
    cy, sy = np.cos(np.radians(yaw / 2)), np.sin(np.radians(yaw / 2))
    cp, sp = np.cos(np.radians(pitch / 2)), np.sin(np.radians(pitch / 2))
    cr, sr = np.cos(np.radians(roll / 2)), np.sin(np.radians(roll / 2))
    q = np.array([sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
                  cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy])
    assert q == pytest.approx(R.from_euler("ZYX", [yaw, pitch, roll], degrees=True).as_quat())
    e = euler_321(np.array([q, [np.nan] * 4]))
    assert e[0] == pytest.approx([yaw, pitch, roll], abs=1e-9)
    assert e[0] == pytest.approx(R.from_quat(q).as_euler("ZYX", degrees=True), abs=1e-12)
    assert np.isnan(e[1]).all()
    # a pure 90° rotation about z is yaw only
    qz = np.array([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])
    assert euler_321(qz)[0] == pytest.approx([90.0, 0.0, 0.0], abs=1e-9)


def test_stream_label_from_stream_info(two_streams, page):
    from monitors.report_ops import stream_label

    d = load_ops(str(two_streams), "p")
    assert d.stream_info[0]["start"] == "cold" and d.stream_info[1]["start"] == "warm"
    lab = stream_label(d, 1)
    assert lab.startswith("stream 1: warm start") and "first t_bus" in lab
    assert "guessed" not in lab
    models = _bokeh_models(page)
    div = next(m for m in models if _attr(m, "name") == "streams:p")
    assert "stream 1: warm start" in _attr(div, "text")
    # stream_info wins over the index-based guess; without it the guess is labelled as such
    d.stream_info[1] = {"index": 1, "start": "cold", "bump": None, "t_bus_first": 0.0}
    assert stream_label(d, 1).startswith("stream 1: cold start")
    d.stream_info.clear()
    assert stream_label(d, 1) == "stream 1: warm start (guessed: no stream_info)"


def test_markers_classify_isolations(two_streams):
    from monitors.report_ops import markers

    d = load_ops(str(two_streams), "p")
    d.fault_x = [(1.0, "GYRO_B_FAILED"), (2.0, "ST1_EDITED"), (3.0, "clear")]
    kinds = [(x, k) for x, k, _label in markers(d) if k != "boundary"]
    assert kinds == [(1.0, "isolation"), (2.0, "fault"), (3.0, "clear")]
