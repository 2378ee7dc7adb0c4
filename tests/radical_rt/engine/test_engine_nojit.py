"""The engine's compiled source run as plain Python (NUMBA_DISABLE_JIT=1), against the compiled run.

The compiled loop (radical_rt/engine/loop.py, steps.py, events.py) and the kernels it calls are
ordinary Python functions under a decorator. Run uncompiled, in a subprocess, on a damaged
150-s stream (a SIRU gap and warm start, invalid and dropped tracker samples, parity sums), they
must give the same output messages byte for byte and the same final state as the compiled run
(the UD factors to the last bits of BLAS-free loops: within 1e-12 relative). The UD and update
kernels' own unit tests run uncompiled as well.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import sys
from pathlib import Path

import msgpack
import numpy as np
import pytest

from tests.support.streams import damaged, input_messages, make_archive

ROOT = Path(__file__).resolve().parents[3]
NOJIT = os.environ.get("NUMBA_DISABLE_JIT") == "1"


def run_stream(archive: str, out: str) -> None:
    """Feed the damaged stream of ``archive`` through radical_rt.apps.batch.make_processor and
    pickle the outputs (topic, msgpack bytes) and the final engine state to ``out``."""
    from radical_rt.apps.batch import make_processor

    sp = make_processor()
    res = []
    for topic, _ns, data in damaged(input_messages(archive)):
        res += [(t, msgpack.packb(m)) for t, m in sp.feed(topic, data)]
    res += [(t, msgpack.packb(m)) for t, m in sp.end_stream(None)]
    e = sp.engine
    state = {k: getattr(e, k).copy() for k in ("U", "d", "xp", "q", "omega", "excluded")}
    with open(out, "wb") as f:
        pickle.dump({"out": res, "state": state, "counters": dict(e.counters),
                     "flags": e.flags, "mode": e.mode}, f)


def _differ(x, y, where: str) -> float:
    """Largest relative difference of the floats of two decoded messages; every other value
    (keys, counts, flags, names) must be equal."""
    if isinstance(x, dict):
        assert isinstance(y, dict) and list(x) == list(y), where
        return max((_differ(x[k], y[k], f"{where}.{k}") for k in x), default=0.0)
    if isinstance(x, list):
        assert isinstance(y, list) and len(x) == len(y), where
        return max((_differ(u, v, f"{where}[{i}]") for i, (u, v) in enumerate(zip(x, y, strict=True))),
                   default=0.0)
    if isinstance(x, float) and isinstance(y, float):
        if x == y or (x != x and y != y):
            return 0.0
        return abs(x - y) / max(abs(x), abs(y))
    assert x == y, f"{where}: {x!r} / {y!r}"
    return 0.0


def _env() -> dict[str, str]:
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1"}
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    return env


@pytest.mark.skipif(NOJIT, reason="already without JIT")
def test_engine_source_uncompiled_gives_the_same_run(tmp_path):
    archive = make_archive(tmp_path, "n", seed=5, duration=150.0)
    run_stream(archive, str(tmp_path / "jit.pkl"))
    code = ("import sys; from tests.radical_rt.engine.test_engine_nojit import run_stream; "
            "run_stream(sys.argv[1], sys.argv[2])")
    r = subprocess.run([sys.executable, "-c", code, str(archive), str(tmp_path / "nojit.pkl")],
                       env=_env(), cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    a = pickle.loads((tmp_path / "jit.pkl").read_bytes())
    b = pickle.loads((tmp_path / "nojit.pkl").read_bytes())
    assert a["counters"]["gyro_gaps"] >= 1 and a["counters"]["parity_used"] > 20
    assert len(a["out"]) == len(b["out"]) > 200
    worst = 0.0
    for i, (x, y) in enumerate(zip(a["out"], b["out"], strict=True)):
        assert x[0] == y[0], f"output {i}: {x[0]} / {y[0]}"
        worst = max(worst, _differ(msgpack.unpackb(x[1]), msgpack.unpackb(y[1]), f"{i} {x[0]}"))
    assert worst < 1e-9, worst
    assert (a["counters"], a["flags"], a["mode"]) == (b["counters"], b["flags"], b["mode"])
    for k, v in a["state"].items():
        np.testing.assert_allclose(b["state"][k], v, rtol=1e-9, atol=1e-300, err_msg=k)


@pytest.mark.skipif(NOJIT, reason="already without JIT")
def test_ud_and_update_kernels_uncompiled():
    """tests/radical_rt/kernels/test_ud.py and test_updates.py with NUMBA_DISABLE_JIT=1."""
    tests = [str(ROOT / "tests/radical_rt/kernels" / f) for f in ("test_ud.py", "test_updates.py")]
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *tests],
                       env=_env(), cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-2000:]
    assert " passed" in r.stdout and "failed" not in r.stdout, r.stdout[-2000:]
