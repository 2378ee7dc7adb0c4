"""`radical report` → calibration_report.html: self-contained, Tables 2–7 with σ, convergence,
residual statistics and NIS recomputed here from the archive, edits and faults, figures inline;
rendered in Debian's Chromium (Playwright; fails, never skips, without it)."""

from __future__ import annotations

import html
import os
import re
from pathlib import Path

import msgpack
import numpy as np
import pytest

from monitors.calreport import stays_below
from radical_rt.apps.batch import process
from radical_rt.apps.cli import main
from radical_rt.io.archive import ArchiveReader
from replayer.synth.api import synthesize

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run"]
ARTIFACTS = Path(__file__).parents[1] / "artifacts"


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    d = tmp_path_factory.mktemp("calrep")
    sim, out = d / "sim.mcap", d / "out.mcap"
    synthesize({"base": "2006216", "t_start_s": 200.0}, sim, seed=21, duration=240.0)
    process([str(sim)], str(out))
    rep = d / "rep"
    assert main(["report", str(out), "-o", str(rep), "--labels", "run21"]) == 0
    return {"out": out, "html": (rep / "calibration_report.html").read_text(), "dir": rep}


def test_stays_below():
    t = np.arange(5.0)
    assert stays_below(t, np.array([0, 1, 0, 1, 1], bool)) == 3.0
    assert stays_below(t, np.array([1, 1, 1, 1, 1], bool)) == 0.0
    assert stays_below(t, np.array([1, 1, 1, 1, 0], bool)) is None


def test_self_contained_with_every_section(report):
    h = report["html"]
    assert "<script" not in h.lower()
    srcs = re.findall(r"src='([^']*)'", h) + re.findall(r'src="([^"]*)"', h)
    assert srcs and all(s.startswith("data:image/png;base64,") for s in srcs)
    assert not re.search(r"href=|url\(|@import", h)
    for title in ("Table 2. ST2 misalignment", "Table 3. Bias b", "Table 4. Symmetric",
                  "Table 5. Asymmetric", "Table 6. Gyro misalignment δu",
                  "Table 7. Gyro misalignment δv", "3. Convergence", "4. Residuals and NIS",
                  "5. Edits and faults", "6. Figures"):
        assert html.escape(title) in h or title in h, title
    assert len(srcs) == 4  # Figures 4, 5, 6 and the operations view (report_ops) of one archive
    assert "run21" in h and "σ_end / σ_0" in h


def _nis(path: Path, kind: str) -> tuple[float, int]:
    vals = []
    with ArchiveReader(path) as r:
        for _t, _ns, data in r.iter_raw("/tlm/large"):
            res = msgpack.unpackb(data).get("residuals", {})
            if kind in res and "nis" in res[kind]:
                vals.append(res[kind]["nis"])
    return float(np.mean(vals)), len(vals)


def test_residual_and_counter_values(report):
    h = report["html"]
    for kind in ("st1", "st2", "parity"):
        mean, n = _nis(report["out"], kind)
        row = re.search(rf"<tr><td>{kind}</td><td>{n}</td>.*?<td class='(ok|bad)'>([-0-9.]+)</td>",
                        h)
        assert row, kind
        assert float(row.group(2)) == pytest.approx(mean, abs=5e-4), kind
    with ArchiveReader(report["out"]) as r:
        last = [msgpack.unpackb(d) for _t, _ns, d in r.iter_raw("/tlm/large")][-1]
    for k in ("st1_used", "st2_used", "siru_missing"):
        assert f"<tr><td>{k}</td><td>{last['counters'][k]}</td></tr>" in h, k


def test_rendered_in_chromium(report):
    assert os.path.exists(CHROMIUM), (f"{CHROMIUM} not found: apt-get update && apt-get install "
                                      "-y chromium (make sysdeps)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError as e:  # pragma: no cover
        pytest.fail(f"playwright missing ({e}): pip install playwright")
    ARTIFACTS.mkdir(exist_ok=True)
    (ARTIFACTS / ".gitignore").write_text("*\n")
    requests: list[str] = []
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        page = b.new_page(viewport={"width": 1280, "height": 1400})
        page.on("request", lambda r: requests.append(r.url))
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto((report["dir"] / "calibration_report.html").as_uri())
        widths = page.eval_on_selector_all("img", "els => els.map(e => e.naturalWidth)")
        tables = page.eval_on_selector_all("table", "els => els.length")
        page.screenshot(path=str(ARTIFACTS / "calibration_report.png"), full_page=True)
        b.close()
    assert widths and all(w > 500 for w in widths), widths
    assert tables >= 14
    assert errors == []
    assert all(u.startswith(("file://", "data:")) for u in requests), requests


def test_pdf(report):
    from monitors.calreport import write_pdf

    assert os.path.exists(CHROMIUM), f"{CHROMIUM} not found: make sysdeps"
    pdf = write_pdf(report["dir"] / "calibration_report.html")
    data = pdf.read_bytes()
    assert data.startswith(b"%PDF") and len(data) > 50_000
    assert len(re.findall(rb"/Type\s*/Page[^s]", data)) >= 3  # tables, residuals, figures
