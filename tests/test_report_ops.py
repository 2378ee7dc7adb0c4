"""`radical report` operations view: streams apart, attitude error, failed gyro, report.html."""

from __future__ import annotations

import re

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from monitors.report import ArchiveData, table_markdown  # noqa: E402
from monitors.report_ops import attitude_error, common_axis, load_ops, split_streams  # noqa: E402
from radical_rt.batch import process  # noqa: E402
from radical_rt.cli import main  # noqa: E402
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
    from monitors.report import load_archive

    d: ArchiveData = load_archive(str(two_streams), "x")
    d.last = dict(d.last, flags=1 << 2)  # GYRO_B_FAILED
    md = table_markdown([d], "b")
    row = next(line for line in md.splitlines() if line.startswith("| x |"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[4].startswith("FAILED") and not cells[2].startswith("FAILED")
