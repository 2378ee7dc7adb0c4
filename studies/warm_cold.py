"""Warm start + bump versus cold start on a second telemetry stream (the paper's §3.1 claim).

    python -m studies.warm_cold [--out DIR] [--duration S] [--seed-a N] [--seed-b N] [--reuse]

Synthesizes 2005301 (bus time from 1000 s) and 2006216 (bus time from 10000 s, after the first
stream), then runs the batch engine twice:

* warm: ``radical process a.mcap b.mcap`` — 2005301, then a warm start with the table's covariance
  bump, then 2006216;
* cold: ``radical process a.mcap b.mcap --cold`` — the same, but the engine cold-starts at the
  second stream. Only the engine's start differs: in both runs the SIRU clock reconstruction keeps
  the oscillator frequency range it learned on the first stream (``SiruClock.reset``), so it locks
  at the first sawtooth wrap of 2006216 (≈ 2.4 min) instead of the second (≈ 6.5 min) for a fresh
  process of 2006216 alone, which is therefore *not* the same as the cold run.

From the ``tlm/large`` telemetry of the 2006216 stream (estimate and 1σ, 1 Hz) and the archive's
``/truth/params`` (interpolated to the telemetry times), per parameter group (b, λ, μ, δu, δv, δa2),
in minutes after the start of the 2006216 stream:

* ``t_conv``: the first time after which, for every element of the group and until the end of the
  stream, σ ≤ the table's convergence threshold (``conv_*``, the engine's own convergence test)
  *and* |error| ≤ 3σ (the σ is honest);
* ``t_err``: the first time after which |error| ≤ the same threshold for every element until the
  end (a truth-only criterion, independent of the filter's σ);
* ``max |e|``: the largest |error| of any element over the whole stream (paper units), and
  ``max |e|/σ``: the largest normalized error (the transient's size in σ);
* the largest |error| of the group at fixed times (5, 10, 20, 30, 40, 60 min), warm / cold.

Writes ``DIR/warm_cold.json`` and ``DIR/warm_cold.md`` (the table of docs/warm_vs_cold.md).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np

from radical_rt.contract.conventions import SI_PER_PAPER_UNIT
from radical_rt.contract.paper_table import ORDER, element_names
from radical_rt.contract.params import ParamTable, to_si
from radical_rt.contract.state import PARAM_GROUPS, StateLayout

T_START_A, T_START_B = 1000.0, 10000.0
CHECKPOINTS_MIN = (5.0, 10.0, 20.0, 30.0, 40.0, 60.0)  # error snapshots (min after the start)
LABELS = {"b": "b (deg/hr)", "lam": "λ (ppm)", "mu": "μ (ppm)", "du": "δu (″)", "dv": "δv (″)",
          "phi2": "δa2 (″)"}


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def thresholds(n_gyro: int = 4) -> dict[str, np.ndarray]:
    """The engine's convergence thresholds (1σ, SI) per contract group, from the default table."""
    si = to_si(ParamTable(n_gyro=n_gyro).active, n_gyro)
    layout = StateLayout(n_gyro)
    conv = np.asarray(si.conv_sigma)
    return {g: conv[layout[g].start - 3:layout[g].stop - 3] for g in PARAM_GROUPS}


def synth_inputs(out: Path, duration: float | None, seed_a: int, seed_b: int) -> tuple[Path, Path]:
    from replayer.synth.api import synthesize

    paths = []
    for base, t0, seed in (("2005301", T_START_A, seed_a), ("2006216", T_START_B, seed_b)):
        toml = out / f"{base}.toml"
        toml.write_text(f'base = "{base}"\nt_start_s = {t0!r}\n')
        path = out / f"{base}.mcap"
        _log(f"synth {base} (seed {seed}) → {path}")
        synthesize(str(toml), path, seed=seed, duration=duration, progress=True)
        paths.append(path)
    return paths[0], paths[1]


def load_track(path: Path, t_min: float) -> dict[str, Any]:
    """``tlm/large`` of an output archive from bus time t_min on: t (k,), est/sigma per group (k, m)."""
    from radical_rt.io.archive import ArchiveReader

    t: list[float] = []
    est: dict[str, list] = {g: [] for g in PARAM_GROUPS}
    sig: dict[str, list] = {g: [] for g in PARAM_GROUPS}
    with ArchiveReader(str(path)) as reader:
        for _topic, _ns, data in reader.iter_raw("/tlm/large"):
            m = msgpack.unpackb(data, raw=False)
            if m["t"] < t_min or m.get("mode") == "init" or "est" not in m:
                continue
            t.append(m["t"])
            for g in PARAM_GROUPS:
                est[g].append(m["est"][g])
                sig[g].append(m["sigma"][g])
    return {"t": np.asarray(t), "est": {g: np.asarray(v) for g, v in est.items()},
            "sigma": {g: np.asarray(v) for g, v in sig.items()}}


def load_truth(path: Path) -> dict[str, Any]:
    from radical_rt.io.archive import ArchiveReader

    t: list[float] = []
    vals: dict[str, list] = {g: [] for g in PARAM_GROUPS}
    with ArchiveReader(str(path)) as reader:
        for _topic, _ns, data in reader.iter_raw("/truth/params"):
            m = msgpack.unpackb(data, raw=False)
            t.append(m["t_bus"])
            for g in PARAM_GROUPS:
                vals[g].append(m[g])
    return {"t": np.asarray(t), **{g: np.asarray(v) for g, v in vals.items()}}


def _settle_time(ok: np.ndarray, t_rel: np.ndarray) -> float:
    """First time after which ``ok`` (k,) holds to the end; NaN if it does not hold at the end."""
    if ok.size == 0 or not ok[-1]:
        return math.nan
    bad = np.nonzero(~ok)[0]
    return float(t_rel[0] if bad.size == 0 else t_rel[bad[-1] + 1])


def metrics(track: dict[str, Any], truth: dict[str, Any], t0: float) -> dict[str, Any]:
    """Per group: convergence times (min), transient maxima, final error (paper units and σ)."""
    thr = thresholds()
    t = track["t"]
    t_rel = (t - t0) / 60.0
    out: dict[str, Any] = {"t_first_min": float(t_rel[0]), "t_last_min": float(t_rel[-1])}
    for g in ORDER:
        k = SI_PER_PAPER_UNIT[g]
        tr = np.stack([np.interp(t, truth["t"], truth[g][:, i]) for i in range(truth[g].shape[1])], 1)
        e, s = track["est"][g] - tr, track["sigma"][g]
        z = np.abs(e) / s
        ok_sigma = np.all((s <= thr[g][None, :]) & (z <= 3.0), axis=1)
        ok_err = np.all(np.abs(e) <= thr[g][None, :], axis=1)
        i_max = np.unravel_index(np.argmax(np.abs(e)), e.shape)
        out[g] = {
            "t_conv_min": _settle_time(ok_sigma, t_rel), "t_err_min": _settle_time(ok_err, t_rel),
            "max_abs_err": float(np.max(np.abs(e)) / k),
            "max_abs_err_at_min": float(t_rel[i_max[0]]),
            "max_abs_err_element": element_names(g, e.shape[1])[i_max[1]],
            "max_err_sigma": float(np.max(z)),
            "max_abs_err_at_checkpoints": {
                f"{c:g}": float(np.max(np.abs(e[min(np.searchsorted(t_rel, c), len(t) - 1)])) / k)
                for c in CHECKPOINTS_MIN},
            "final_err": (e[-1] / k).tolist(), "final_sigma": (s[-1] / k).tolist(),
            "final_err_sigma": (e[-1] / s[-1]).tolist(), "threshold": (thr[g] / k).tolist()}
    return out


def _fmt_t(x: float) -> str:
    return "never" if not math.isfinite(x) else f"{x:.1f}"


def _fmt_v(x: float) -> str:
    return f"{x:.3g}" if abs(x) < 1000 else f"{x:.0f}"


def table(res: dict[str, Any]) -> str:
    w, c = res["warm"], res["cold"]
    lines = ["| group | t_conv warm | t_conv cold | t_err warm | t_err cold | max \\|e\\| warm | "
             "max \\|e\\| cold | max \\|e\\|/σ warm | max \\|e\\|/σ cold | final max \\|e\\|/σ warm | "
             "final max \\|e\\|/σ cold |", "|---" * 11 + "|"]
    for g in ORDER:
        lines.append(
            f"| {LABELS[g]} | {_fmt_t(w[g]['t_conv_min'])} | {_fmt_t(c[g]['t_conv_min'])} | "
            f"{_fmt_t(w[g]['t_err_min'])} | {_fmt_t(c[g]['t_err_min'])} | "
            f"{_fmt_v(w[g]['max_abs_err'])} | {_fmt_v(c[g]['max_abs_err'])} | "
            f"{w[g]['max_err_sigma']:.2f} | {c[g]['max_err_sigma']:.2f} | "
            f"{max(abs(x) for x in w[g]['final_err_sigma']):.2f} | "
            f"{max(abs(x) for x in c[g]['final_err_sigma']):.2f} |")
    return "\n".join(lines)


def checkpoint_table(res: dict[str, Any]) -> str:
    """Largest |error| of each group at fixed times after the stream start, warm / cold."""
    cps = list(res["warm"][ORDER[0]]["max_abs_err_at_checkpoints"])
    lines = ["| group | " + " | ".join(f"{c} min" for c in cps) + " |", "|---" * (len(cps) + 1) + "|"]
    for g in ORDER:
        w = res["warm"][g]["max_abs_err_at_checkpoints"]
        c = res["cold"][g]["max_abs_err_at_checkpoints"]
        lines.append(f"| {LABELS[g]} | " + " | ".join(f"{_fmt_v(w[k])} / {_fmt_v(c[k])}" for k in cps)
                     + " |")
    return "\n".join(lines)


def run(out: Path, duration: float | None = None, seed_a: int = 2005301, seed_b: int = 2006216,
        reuse: bool = False) -> dict[str, Any]:
    from radical_rt.apps.batch import process

    out.mkdir(parents=True, exist_ok=True)
    a, b = out / "2005301.mcap", out / "2006216.mcap"
    if not (reuse and a.exists() and b.exists()):
        a, b = synth_inputs(out, duration, seed_a, seed_b)
    warm, cold = out / "warm.mcap", out / "cold.mcap"
    for name, path in (("warm", warm), ("cold", cold)):
        if reuse and path.exists():
            continue
        _log(f"process ({name}): {a.name} + {b.name} → {path}")
        t0 = time.perf_counter()
        process([str(a), str(b)], str(path), str(out / f"{name}_summary.json"),
                cold=name == "cold", progress=True)
        _log(f"  {time.perf_counter() - t0:.1f} s")
    truth = load_truth(b)
    t0 = float(truth["t"][0])
    res = {"inputs": {"2005301": {"seed": seed_a, "t_start_s": T_START_A},
                      "2006216": {"seed": seed_b, "t_start_s": T_START_B}},
           "duration_s": duration, "stream_start_bus_s": t0}
    for name, path in (("warm", warm), ("cold", cold)):
        res[name] = metrics(load_track(path, t0), truth, t0)
    (out / "warm_cold.json").write_text(json.dumps(res, indent=1) + "\n")
    (out / "warm_cold.md").write_text(table(res) + "\n\n" + checkpoint_table(res) + "\n")
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out/warm_cold", help="working and result directory")
    ap.add_argument("--duration", type=float, default=None,
                    help="length of each stream, s (default: the scenarios' 7200 s)")
    ap.add_argument("--seed-a", type=int, default=2005301, help="seed of the 2005301 stream")
    ap.add_argument("--seed-b", type=int, default=2006216, help="seed of the 2006216 stream")
    ap.add_argument("--reuse", action="store_true", help="reuse archives already in --out")
    a = ap.parse_args(argv)
    res = run(Path(a.out), a.duration, a.seed_a, a.seed_b, a.reuse)
    print(table(res))
    print()
    print(checkpoint_table(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
