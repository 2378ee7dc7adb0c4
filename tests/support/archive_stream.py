"""A synthetic archive stream for the archive tests (tests/radical_rt/io): every topic of the
contract plus an unknown one, SIRU in one large and many one-sample batches, messages written out
of log_time order; the expected raw messages and a writer."""

from __future__ import annotations

import warnings

import msgpack
import numpy as np

from radical_rt.contract.conventions import t_to_ns
from radical_rt.io.archive import (
    ArchiveReader,
    ArchiveWriter,
)

SCENARIO = {"name": "unit", "vehicle": "sc1", "seed": "7", "generator": "tests", "extra": "x"}
PARAM_KEYS = ("b", "lam", "mu", "du", "dv", "phi2")


def quat(rng):
    q = rng.normal(size=4)
    return (q / np.linalg.norm(q)).tolist()


def params(rng, scale=1e-6):
    return {k: rng.normal(0, scale, 3 if k == "phi2" else 4).tolist() for k in PARAM_KEYS}


def siru_msg(rng, t0, k, i0):
    """A siru message of k reads from bus time t0 [s], time tags from read i0."""
    return {"v": 1, "t_bus": [t0 + 0.01 * i + 0.0031 for i in range(k)],
            "tt": [((i0 + i) * 10000) % (1 << 32) for i in range(k)],
            "dtheta": rng.normal(0, 1e-5, (k, 4)).tolist(), "status": [0] * k}


def make_stream(seed=1, seconds=6):
    """(topic, msg, t_bus) in write order: every topic of the contract plus an unknown one.

    SIRU alternates one 100-sample batch and 100 one-sample batches per second; trackers and
    temperatures are written after the batch that covers them (out of log_time order)."""
    rng = np.random.default_rng(seed)
    out = []
    i0 = (1 << 32) - 30000  # tt wraps during the first second
    for s in range(seconds):
        t0 = 1000.0 + s
        if s % 2 == 0:
            m = siru_msg(rng, t0, 100, i0)
            out.append(("/siru", m, m["t_bus"][-1]))
        else:
            for i in range(100):
                m = siru_msg(rng, t0 + 0.01 * i, 1, i0 + i)
                out.append(("/siru", m, m["t_bus"][-1]))
        out.append(("/truth/siru_time", {"v": 1, "tt": [((i0 + i) * 10000) % (1 << 32) for i in
                                                          range(100)],
                                         "t_true": [t0 + 0.01 * i for i in range(100)]},
                    t0 + 0.99))
        i0 += 100
        for j, dt in ((1, 0.25), (2, 0.30), (1, 0.75), (2, 0.80)):
            out.append((f"/st{j}", {"v": 1, "t_bus": t0 + dt, "q": quat(rng), "n_stars": 9,
                                    "valid": bool(dt < 0.5)}, t0 + dt))
        out.append(("/temp", {"v": 1, "t_bus": t0 + 0.5, "st1_baseplate_C": 20.0 + s,
                              "siru_C": 25.5}, t0 + 0.5))
        for k in range(10):
            t = t0 + 0.1 * k
            out.append(("/truth/attitude", {"v": 1, "t_bus": t, "q_body_from_inertial": quat(rng),
                                            "omega_body": rng.normal(0, 1e-3, 3).tolist()}, t))
        out.append(("/truth/params", {"v": 1, "t_bus": t0, **params(rng)}, t0))
        small = {"v": 1, "seq": s, "t": t0 + 0.9, "q_body_from_inertial": quat(rng),
                 "flags": 1 << 13, "mode": "converging"}
        medium = {**small, "omega_body": [0.0, 1e-3, 0.0], "est": params(rng)}
        large = {**medium, "sigma": {k: np.abs(v).tolist() for k, v in params(rng).items()},
                 "att_sigma": [1e-5, 1e-5, 2e-5], "counters": {"siru_samples": 100 * s},
                 "clock": {"eps": 3e-5}}
        for topic, m in (("/tlm/small", small), ("/tlm/medium", medium), ("/tlm/large", large)):
            out.append((topic, m, m["t"]))
        out.append(("/fault", {"v": 1, "t": t0 + 0.9, "flags": 1 << 13, "set": ["NOT_CONVERGED"],
                               "cleared": [], "detail": {}}, t0 + 0.9))
        out.append(("/diag", {"v": 1, "t": t0 + 0.9, "nis": [1.2, 0.8]}, t0 + 0.9))
        out.append(("/custom/thing", {"t": t0 + 0.95, "x": b"\x00\x01"}, t0 + 0.95))
    return out


def expected_raw(stream):
    raw = [(topic, t_to_ns(t), msgpack.packb(m, use_bin_type=True)) for topic, m, t in stream]
    return sorted(raw, key=lambda r: r[1])  # stable: ties keep write order


def write_stream(path, stream, *, flush_every=None, **kw):
    with ArchiveWriter(path, scenario=SCENARIO, chunk_size=kw.pop("chunk_size", 8192), **kw) as w:
        for n, (topic, m, _t) in enumerate(stream):
            w.write(topic, m)  # time from the message itself
            if flush_every and n % flush_every == flush_every - 1:
                w.flush()
    return path


def strict_reader(path, **kw):
    """An ArchiveReader that turns any warning into an error."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return ArchiveReader(path, **kw)


