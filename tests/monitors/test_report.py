"""`radical report`: paper Tables 2–7 (Markdown + CSV) and Figures 4–8 (PNG) from output archives."""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("matplotlib", reason="pip install matplotlib (radical report)")

from radical_rt.apps.batch import process  # noqa: E402
from radical_rt.apps.cli import main  # noqa: E402
from radical_rt.contract.conventions import to_paper_units  # noqa: E402
from radical_rt.contract.paper_table import ORDER, element_names  # noqa: E402
from radical_rt.io.archive import ArchiveReader  # noqa: E402
from replayer.synth.api import synthesize  # noqa: E402

TABLES = {"phi2": "table2_phi2", "b": "table3_b", "lam": "table4_lam", "mu": "table5_mu",
          "du": "table6_du", "dv": "table7_dv"}


@pytest.fixture(scope="module")
def archives(tmp_path_factory):
    """Two short processed archives: stream A alone, and A then B with a warm start."""
    d = tmp_path_factory.mktemp("report")
    a, b = d / "a.mcap", d / "b.mcap"
    synthesize({"base": "2006216", "t_start_s": 1000.0}, a, seed=3, duration=150.0)
    synthesize({"base": "2006216", "t_start_s": 3000.0}, b, seed=4, duration=120.0)
    one, two = d / "one.mcap", d / "warm.mcap"
    process([str(a)], str(one))
    process([str(a), str(b)], str(two))
    return {"dir": d, "inputs": (a, b), "one": one, "warm": two}


def last_large(path: Path) -> dict:
    with ArchiveReader(path) as r:
        msgs = [m for _t, _ns, m in r.iter_messages("/tlm/large")]
    return msgs[-1]


def read_csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def assert_png_nontrivial(path: Path, min_w: int = 600, min_h: int = 400) -> None:
    from PIL import Image

    assert path.exists(), path
    img = np.asarray(Image.open(path).convert("RGB"))
    h, w, _ = img.shape
    assert w >= min_w and h >= min_h, (path, img.shape)
    colours = np.unique(img.reshape(-1, 3)[::7], axis=0)
    assert len(colours) > 50, f"{path}: only {len(colours)} colours"
    assert img.std() > 10, f"{path}: nearly uniform"


def test_report_one_archive(archives, tmp_path, capsys):
    out = tmp_path / "rep"
    assert main(["report", str(archives["one"]), "-o", str(out)]) == 0
    assert "figures" in capsys.readouterr().out
    last = last_large(archives["one"])
    for g, stem in TABLES.items():
        md = (out / f"{stem}.md").read_text()
        rows = read_csv(out / f"{stem}.csv")
        assert len(rows) == 1 and rows[0]["label"] == "one"
        est = to_paper_units(g, np.asarray(last["est"][g]))
        sig = to_paper_units(g, np.asarray(last["sigma"][g]))
        names = element_names(g, len(est))
        for i, name in enumerate(names):
            unit = {"b": "deg/hr", "lam": "ppm", "mu": "ppm"}.get(g, "arcsec")
            assert float(rows[0][f"{name} estimate [{unit}]"]) == pytest.approx(est[i], rel=1e-12)
            assert float(rows[0][f"{name} sigma [{unit}]"]) == pytest.approx(sig[i], rel=1e-12)
            # truth present (the output archive copies /truth/params): truth and err/σ columns
            tr = float(rows[0][f"{name} truth [{unit}]"])
            assert float(rows[0][f"{name} err/sigma"]) == pytest.approx((est[i] - tr) / sig[i],
                                                                        rel=1e-6, abs=1e-9)
        assert float(rows[0]["t_end_s"]) == pytest.approx(last["t"])
        # Markdown: paper layout, one row per archive, estimate then σ per element
        assert md.startswith(f"### Table {list(TABLES).index(g) + 2}.")
        header = next(line for line in md.splitlines() if line.startswith("| Archive"))
        assert header.count("σ") == len(names)
        assert "Truth (/truth/params at t_end) and error/σ" in md
    all_md = (out / "tables.md").read_text()
    assert all(f"Table {n}." in all_md for n in range(2, 8))
    for fig in ("fig4_one.png", "fig5_one.png", "fig6_one.png"):
        assert_png_nontrivial(out / fig)
    assert not (out / "fig7.png").exists()  # side by side needs ≥ 2 archives
    html = (out / "index.html").read_text()
    srcs = re.findall(r"(?:src|href)='([^']+)'", html)
    assert {"fig4_one.png", "fig5_one.png", "fig6_one.png", "table3_b.csv"} <= set(srcs)
    assert all(not s.startswith(("http:", "https:", "/", "//")) for s in srcs)
    assert "<script" not in html and "http://" not in html and "https://" not in html
    assert "<th>Gyro A b</th>" in html


def test_report_side_by_side_and_decimation(archives, tmp_path):
    out = tmp_path / "rep2"
    rc = main(["report", str(archives["warm"]), str(archives["one"]), "-o", str(out),
               "--labels", "warm,cold", "--max-points", "40"])
    assert rc == 0
    lasts = {"warm": last_large(archives["warm"]), "cold": last_large(archives["one"])}
    for g, stem in TABLES.items():
        rows = read_csv(out / f"{stem}.csv")
        assert [r["label"] for r in rows] == ["warm", "cold"]
        for r in rows:  # decimation never touches the tables: exactly the last packet
            est = to_paper_units(g, np.asarray(lasts[r["label"]]["est"][g]))
            name = element_names(g, len(est))[0]
            col = next(k for k in r if k.startswith(f"{name} estimate"))
            assert float(r[col]) == pytest.approx(est[0], rel=1e-12)
        md = (out / f"{stem}.md").read_text()
        assert "| warm |" in md and "| cold |" in md
    for fig in ("fig4_warm.png", "fig5_cold.png", "fig6_warm.png"):
        assert_png_nontrivial(out / fig)
    assert_png_nontrivial(out / "fig7.png", min_w=900)
    assert_png_nontrivial(out / "fig8.png", min_w=900)
    html = (out / "index.html").read_text()
    assert "fig7.png" in html and "fig8.png" in html


def test_report_errors(archives, tmp_path, capsys):
    out = str(tmp_path / "x")
    cases = [
        ([str(tmp_path / "missing.mcap")], "no such file"),
        ([str(Path(__file__))], "not an MCAP archive"),
        ([str(archives["inputs"][0])], "no telemetry channels"),  # an input archive
        ([str(archives["one"]), "--labels", "a,b"], "--labels"),
    ]
    for args, text in cases:
        assert main(["report", *args, "-o", out]) == 2
        err = capsys.readouterr().err.strip()
        assert text in err and err.startswith("radical report:") and "\n" not in err, err


def test_report_tables_only_is_fast(archives, tmp_path):
    import time

    t0 = time.perf_counter()
    assert main(["report", str(archives["warm"]), "-o", str(tmp_path / "t"), "--no-figures"]) == 0
    assert time.perf_counter() - t0 < 5.0
    assert {p.name for p in (tmp_path / "t").iterdir()} >= {f"{s}.csv" for s in TABLES.values()}
    assert list(ORDER) == list(TABLES)
