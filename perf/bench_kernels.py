"""UD kernel micro-benchmarks at n = 26 against a dense numpy step and filterpy.

Command::

    python -m perf.bench_kernels [--profile smoke|quick|full] [--out DIR] [--no-compile]

Writes ``DIR/kernels_<profile>.json`` (default DIR: perf/results) and prints a Markdown table.
From code: ``perf.bench_kernels.run(profile="quick", out_dir=None) -> dict``.

How to read the table (all times are µs per call, Python call overhead included, ≈ 0.3 µs):

* ``UD best`` / ``UD p99``: the radical_rt.kernels.ud / ud_time kernel; best = the lowest mean over ``repeat``
  loops of ``number`` calls; p99 = 99th percentile of individually timed calls (tail latency).
* ``dense numpy``: the same step on a dense P with numpy (Joseph form
  (I−Kh)P(I−Kh)ᵀ + rKKᵀ for an update, ΦPΦᵀ + Q for a time update, P + c aaᵀ, P_ii += c).
* ``filterpy``: ``KalmanFilter.update`` (dim_z = 1, Joseph form) or ``KalmanFilter.predict``
  with dim_x = 26; "n/a" where filterpy has no equivalent or could not be used.
* ``×dense``, ``×filterpy``: speed-up of the UD kernel (reference best / UD best).

JIT: a fresh interpreter with an empty ``NUMBA_CACHE_DIR`` measures the cold compile (first call
of each kernel); a second fresh interpreter on the same cache directory measures the cache load.
Inputs are seeded and built outside the timed regions. Numbers are machine-dependent: compare
ratios, not absolute values, across machines.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

N = 26  # states (attitude 3 + 23 parameters)
M_ATT = 3
SEED = 2005300
PROFILES = {  # number of calls per timed loop, loops (best of), individually timed calls
    "smoke": dict(number=20, repeat=2, samples=50),
    "quick": dict(number=2000, repeat=5, samples=2000),
    "full": dict(number=20000, repeat=9, samples=20000),
}
DEFAULT_OUT = Path(__file__).resolve().parent / "results"
ROOT = Path(__file__).resolve().parent.parent

# Run in a fresh interpreter: first call of every kernel (compile, or load from the cache).
_COMPILE_SCRIPT = r"""
import json, sys, time
t0 = time.perf_counter()
import numba  # noqa: F401
t1 = time.perf_counter()
import numpy as np
from radical_rt.kernels import ud, ud_time
t2 = time.perf_counter()
n = 26; ws = ud.UDWorkspace(n); U = np.zeros((n, n)); d = np.zeros(n)
calls = {
    "factor_ud": lambda: ud.factor_ud(np.eye(n), U, d),
    "bierman_update": lambda: ud.bierman_update(U, d, np.ones(n), 1.0, ws.k, ws.f, ws.v),
    "structured_time_update": lambda: ud_time.structured_time_update(
        U, d, 3, np.eye(3), np.zeros((3, n - 3)), np.eye(3), ws.struct),
    "mwgs_time_update": lambda: ud_time.mwgs_time_update(U, d, np.eye(n), np.eye(n), np.ones(n),
                                                    ws.Y, ws.Dw, ws.c),
    "agee_turner": lambda: ud_time.agee_turner(U, d, 1.0, np.ones(n), ws.a),
    "add_diagonal_noise": lambda: ud_time.add_diagonal_noise(U, d, np.arange(3, n), np.ones(n - 3),
                                                        ws.a),
}
first = {}
for name, call in calls.items():
    t = time.perf_counter(); call(); first[name] = time.perf_counter() - t
print(json.dumps({"import_numba_s": t1 - t0, "import_module_s": t2 - t1, "first_call_s": first,
                  "total_first_calls_s": sum(first.values())}))
"""


def _subprocess_first_calls(cache_dir: str) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache_dir)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    out = subprocess.run([sys.executable, "-c", _COMPILE_SCRIPT], env=env, cwd=str(ROOT),
                         capture_output=True, text=True, check=True, timeout=600)
    return json.loads(out.stdout.strip().splitlines()[-1])


def measure_jit() -> dict:
    """Cold compile (empty cache) and cache load, each in a fresh interpreter."""
    with tempfile.TemporaryDirectory(prefix="radical-numba-") as cache_dir:
        cold = _subprocess_first_calls(cache_dir)
        warm = _subprocess_first_calls(cache_dir)
    return {"method": "fresh subprocess, NUMBA_CACHE_DIR=<new temp dir>",
            "cold_compile_s": cold["total_first_calls_s"],
            "cache_load_s": warm["total_first_calls_s"],
            "import_numba_s": warm["import_numba_s"], "cold": cold, "cache": warm}


def _time(fn, number: int, repeat: int, samples: int) -> dict:
    """best/median of ``repeat`` loop means and p50/p99/max of ``samples`` single calls (µs)."""
    fn()
    loops = []
    for _ in range(repeat):
        t0 = time.perf_counter_ns()
        for _ in range(number):
            fn()
        loops.append((time.perf_counter_ns() - t0) / number / 1e3)
    single = np.empty(samples)
    clock = time.perf_counter_ns
    for i in range(samples):
        t0 = clock()
        fn()
        single[i] = clock() - t0
    single /= 1e3
    return {"best_us": min(loops), "median_us": statistics.median(loops),
            "p50_us": float(np.percentile(single, 50)), "p99_us": float(np.percentile(single, 99)),
            "max_us": float(single.max())}


def _problem(rng):
    """Filter-like prior and model: attitude first, Φ = [[R, Φ_ap], [0, I]], sparse tracker row."""
    s = np.concatenate([np.full(3, 1e-3), np.full(20, 1e-5), np.full(3, 1e-4)])  # σ, SI-like
    Q0, _ = np.linalg.qr(rng.standard_normal((N, N)))
    C = (Q0 * 10.0 ** rng.uniform(-2, 0, N)) @ Q0.T
    P = s[:, None] * (C + C.T) / 2 * s[None, :] + np.diag(s**2) * 1e-3
    w = rng.standard_normal(3) * 1e-3
    K = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    Phi = np.eye(N)
    Phi[:3, :3] += K + 0.5 * K @ K
    Phi[:3, 3:] = rng.standard_normal((3, N - 3)) * 1e-2
    Q_aa = np.diag(np.full(3, 1e-12))
    h_dense = rng.standard_normal(N) / s
    h_sparse = np.zeros(N)
    h_sparse[[0, 1, 2, 23, 24, 25]] = rng.standard_normal(6)
    return P, Phi, Q_aa, h_dense, h_sparse


def _filterpy(P, Phi, Q):
    """filterpy KalmanFilter (dim_x = N, dim_z = 1) or the reason it cannot be used."""
    try:
        import filterpy
        from filterpy.kalman import KalmanFilter

        kf = KalmanFilter(dim_x=N, dim_z=1)
        kf.P, kf.F, kf.Q, kf.R = P.copy(), Phi.copy(), Q.copy(), np.eye(1) * 1e-10
        kf.update(np.zeros(1), H=np.ones((1, N)))
        kf.predict()
        kf.P = P.copy()
        return kf, getattr(filterpy, "__version__", "?"), None
    except Exception as exc:  # old filterpy vs new numpy, missing package, ...
        return None, None, f"{type(exc).__name__}: {exc}"


def run_kernels(number: int, repeat: int, samples: int) -> tuple[dict, dict]:
    """Time every case; returns (results, info)."""
    from radical_rt.kernels import ud, ud_time

    rng = np.random.default_rng(SEED)
    P, Phi, Q_aa, h_dense, h_sparse = _problem(rng)
    Q = np.zeros((N, N))
    Q[:3, :3] = Q_aa
    r = 1e-10
    ws = ud.UDWorkspace(N, m_att=M_ATT)
    a = rng.standard_normal(N) * 1e-5
    idx = np.arange(M_ATT, N)
    c_noise = np.full(N - M_ATT, 1e-14)
    G3, q3 = np.vstack([np.eye(3), np.zeros((N - 3, 3))]), np.diag(Q_aa).copy()
    G26, q26 = np.eye(N), np.full(N, 1e-14)
    Phi_aa, Phi_ap = Phi[:3, :3].copy(), Phi[:3, 3:].copy()

    def fresh():
        U, d = np.zeros((N, N)), np.zeros(N)
        assert ud.factor_ud(P, U, d) == 0
        return U, d

    kf, fp_version, fp_error = _filterpy(P, Phi, Q)
    z, H_dense, H_sparse = np.zeros(1), h_dense[None, :], h_sparse[None, :]
    eye = np.eye(N)

    def joseph(Pd, h):
        Ph = Pd @ h
        k = Ph / (h @ Ph + r)
        A = eye - np.outer(k, h)
        Pd[:] = A @ Pd @ A.T + r * np.outer(k, k)

    def dense_predict(Pd, Qd=Q):
        Pd[:] = Phi @ Pd @ Phi.T + Qd

    def dense_rank_one(Pd):
        Pd += np.outer(a, a)

    def dense_diag(Pd):
        Pd[idx, idx] += c_noise

    fp_update = kf.update if kf is not None else None
    fp_predict = kf.predict if kf is not None else None
    Case = tuple[Callable[..., Any], tuple, Callable[..., Any], Callable[..., Any] | None]
    cases: dict[str, Case] = {  # name: (UD kernel, args after (U, d), dense step, filterpy call)
        "bierman_update": (ud.bierman_update, (h_dense, r, ws.k, ws.f, ws.v),
                           partial(joseph, h=h_dense),
                           fp_update and partial(fp_update, z, r, H_dense)),
        "bierman_update_sparse_st": (ud.bierman_update, (h_sparse, r, ws.k, ws.f, ws.v),
                                     partial(joseph, h=h_sparse),
                                     fp_update and partial(fp_update, z, r, H_sparse)),
        "structured_time_update": (ud_time.structured_time_update,
                                   (M_ATT, Phi_aa, Phi_ap, Q_aa, ws.struct), dense_predict,
                                   fp_predict),
        "mwgs_time_update_r3": (ud_time.mwgs_time_update, (Phi, G3, q3, ws.Y, ws.Dw, ws.c),
                                dense_predict, fp_predict),
        "mwgs_time_update_r26": (ud_time.mwgs_time_update, (Phi, G26, q26, ws.Y, ws.Dw, ws.c),
                                 partial(dense_predict, Qd=np.diag(q26)), None),
        "agee_turner": (ud_time.agee_turner, (1.0, a, ws.a), dense_rank_one, None),
        "add_diagonal_noise_23": (ud_time.add_diagonal_noise, (idx, c_noise, ws.a), dense_diag, None),
    }
    results = {}
    for name, (kernel, args, dense_step, fp_call) in cases.items():
        U, d = fresh()
        Pd = P.copy()
        ud_call, dense_call = partial(kernel, U, d, *args), partial(dense_step, Pd)
        status = ud_call()  # one step each, checked against the dense step, before timing
        status = status[0] if isinstance(status, tuple) else status
        dense_call()
        Pu = np.empty((N, N))
        ud.ud_to_cov(U, d, Pu)
        sd = np.sqrt(np.diag(Pd))
        err = float(np.max(np.abs(Pu - Pd) / np.outer(sd, sd)))
        if status != 0 or not err < 1e-8:
            raise RuntimeError(f"{name}: UD and dense disagree (status {status}, error {err:.2e})")
        row = {"ud": _time(ud_call, number, repeat, samples),
               "dense_numpy": _time(dense_call, number, repeat, samples),
               "filterpy": None, "check_max_err": err}
        final = ud_call()  # the timed calls stayed on the normal (status OK) path
        if (final[0] if isinstance(final, tuple) else final) != 0:
            raise RuntimeError(f"{name}: status {final} after the timed calls")
        if fp_call is not None:
            kf.P = P.copy()
            row["filterpy"] = _time(fp_call, number, repeat, samples)
        results[name] = row
    info = {"filterpy_version": fp_version, "filterpy_error": fp_error}
    return results, info


def markdown(report: dict) -> str:
    """The Markdown table of a report (see the module docstring for the columns)."""
    lines = [f"UD kernels, n = {report['n']}, profile {report['profile']} (µs per call)", "",
             "| kernel | UD best | UD p99 | dense numpy | filterpy | ×dense | ×filterpy |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for name, row in report["results"].items():
        ud_b, dn = row["ud"]["best_us"], row["dense_numpy"]["best_us"]
        fp = row["filterpy"]["best_us"] if row["filterpy"] else None
        lines.append(f"| {name} | {ud_b:.2f} | {row['ud']['p99_us']:.2f} | {dn:.2f} | "
                     + (f"{fp:.2f}" if fp else "n/a") + f" | {dn / ud_b:.1f} | "
                     + (f"{fp / ud_b:.1f}" if fp else "n/a") + " |")
    jit = report.get("jit")
    if jit:
        lines += ["", f"JIT (first call of {len(jit['cold']['first_call_s'])} kernels, fresh "
                  f"interpreter): cold compile {jit['cold_compile_s']:.2f} s, cache load "
                  f"{jit['cache_load_s']:.3f} s (import numba {jit['import_numba_s']:.2f} s)"]
    return "\n".join(lines)


def run(profile: str = "quick", out_dir: str | os.PathLike | None = None,
        compile_times: bool = True) -> dict:
    """Run the benchmark, write ``<out_dir>/kernels_<profile>.json``, return the report dict."""
    if profile not in PROFILES:
        raise ValueError(f"unknown profile {profile!r}; choose from {sorted(PROFILES)}")
    import numba

    params = PROFILES[profile]
    jit = measure_jit() if compile_times else None
    results, info = run_kernels(**params)
    report = {
        "schema": "radical.bench.kernels/1", "profile": profile, "n": N, "seed": SEED,
        "params": params, "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "machine": {"python": platform.python_version(), "platform": platform.platform(),
                    "processor": platform.processor(), "cpu_count": os.cpu_count(),
                    "numpy": np.__version__, "numba": numba.__version__, **info},
        "jit": jit, "results": results,
    }
    out = Path(out_dir) if out_dir is not None else DEFAULT_OUT
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"kernels_{profile}.json"
    path.write_text(json.dumps(report, indent=2, allow_nan=False))
    report["json_path"] = str(path)
    return report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--profile", choices=sorted(PROFILES), default="quick")
    parser.add_argument("--out", default=str(DEFAULT_OUT), help="output directory for the JSON")
    parser.add_argument("--no-compile", action="store_true", help="skip the JIT subprocess timing")
    args = parser.parse_args(argv)
    report = run(args.profile, args.out, compile_times=not args.no_compile)
    print(markdown(report))
    print(f"\nwrote {report['json_path']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
