"""Fuzz benchmark of the node's commands and checkpoints (issue 23 part A).

    python -m perf.fuzz_commands [--commands 10000] [--checkpoints 1000] [--seed 23]
                                 [--feed 4] [--out perf/results/fuzz_commands.json]

Commands (:func:`perf.fuzz_cases.command_case`, half valid-but-extreme, half invalid) go to an
in-memory :class:`~radical_rt.apps.node.FilterNode` that is fed a simulated stream (``--feed``
input messages after every command). Damaged checkpoints (:func:`perf.fuzz_cases.
checkpoint_case`) are read and restored into a processor. Counted, all expected to be 0:

* crashes (the worker process died, e.g. a segfault) and hangs (no progress for ``HANG_S``);
* internal errors (a reply "internal error", an ``internal_error`` input rejection, or an
  exception escaping :func:`radical_rt.io.checkpoint.restore` other than CheckpointError);
* state changes by refused commands or checkpoints, invalid commands accepted, and NUMERIC
  still set after a cold start (``numeric_stuck``).

Cases run in a worker process watched by this one: a crash or hang is recorded for the case
and the worker restarts at the next case. Every case is a function of (seed, index).
"""

from __future__ import annotations

import argparse
import json
import os
import select
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

HANG_S = 60.0  # no result line for this long: the case hangs
ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "perf" / "results" / "fuzz_commands.json"


# ------------------------------------------------------------------------------------ worker side
def _archive(directory: Path, seed: int) -> Path:
    from replayer.synth.api import synthesize
    sc = directory / "fuzz.toml"
    sc.write_text('base = "2006216"\nt_start_s = 1000.0\n')
    out = directory / "fuzz.mcap"
    if not out.exists():
        synthesize(str(sc), out, seed=seed, duration=60)
    return out


def _messages(path: Path) -> list[tuple[str, bytes]]:
    from radical_rt.io.archive import ArchiveReader
    with ArchiveReader(path) as r:
        return [(t[1:], data) for t, _ns, data in r.iter_raw(topics=["/siru", "/st1", "/st2", "/temp"])]


class CommandRig:
    """An in-memory node fed the stream, commands sent through its queryable."""

    def __init__(self, msgs: list[tuple[str, bytes]], ckdir: Path, feed: int) -> None:
        from radical_rt.apps.node import FilterNode
        from radical_rt.apps.node_setup import build_processors
        from radical_rt.io.mem_transport import InMemoryBus, InMemoryTransport
        self.msgs, self.feed_n, self.pos = msgs, feed, 0
        self.bus = InMemoryBus(threaded=False)
        self.node = FilterNode(InMemoryTransport(self.bus), build_processors(["v1"]),
                               checkpoint_path=str(ckdir / "node.ckpt"), command_timeout_s=30.0)
        self.client = InMemoryTransport(self.bus)
        self.node.start()
        self.feed(len(msgs) // 3)  # attitude initialized, converging

    def sp(self):
        return self.node.vehicles["v1"].sp

    def cmd(self, req: dict) -> dict:
        import msgpack
        raw = msgpack.packb(req, use_bin_type=True)
        replies = self.client.get("radical/v1/cmd", raw, timeout=HANG_S)
        return msgpack.unpackb(replies[0], raw=False, strict_map_key=False) if replies else {}

    def feed(self, n: int) -> bool:
        for _ in range(n):
            if self.pos >= len(self.msgs):  # the archive again, as a new stream
                self.cmd({"cmd": "end_stream", "next": "cold"})
                self.pos = 0
            topic, data = self.msgs[self.pos]
            self.pos += 1
            self.client.put(f"radical/v1/{topic}", data, block=True)
        return self.node.wait_idle(HANG_S)

    def state(self) -> bytes:
        import msgpack

        from radical_rt.io.checkpoint import capture
        self.node.wait_idle(HANG_S)
        return msgpack.packb(capture(self.sp(), "v1"), use_bin_type=True)

    def case(self, seed: int, i: int) -> dict:
        from perf.fuzz_cases import command_case
        req, valid = command_case(seed, i)
        sp = self.sp()
        ie0 = sp.rejected.get("internal_error", 0)
        before = None if valid else self.state()
        reply = self.cmd(req)
        out = {"i": i, "cmd": str(req.get("cmd"))[:20], "valid": valid, "ok": bool(reply.get("ok"))}
        if not reply:
            out["hang"] = 1
        if "internal error" in str(reply.get("error", "")):
            out["internal"] = 1
        if not valid:
            out["accepted_invalid"] = int(bool(reply.get("ok")))
            out["state_change"] = int(self.state() != before)
        elif not reply.get("ok"):
            out["refused_valid"] = 1  # state-dependent refusals (e.g. a 4th gyro excluded)
            out["error"] = str(reply.get("error"))[:160]
        if not self.feed(self.feed_n):
            out["hang"] = 1
        if i % 25 == 24:  # back to a healthy start: NUMERIC must clear
            self.cmd({"cmd": "reset_params"})
            for g in range(4):
                self.cmd({"cmd": "include_gyro", "gyro": g})
            self.cmd({"cmd": "cold_start"})
            out["numeric_stuck"] = int(bool(self.sp().engine.flags & (1 << 11)))
        out["internal"] = out.get("internal", 0) + sp.rejected.get("internal_error", 0) - ie0
        return out


class CheckpointRig:
    """Damaged checkpoints read and restored into a processor."""

    def __init__(self, msgs: list[tuple[str, bytes]], ckdir: Path) -> None:
        from radical_rt.apps.batch import make_processor
        from radical_rt.io import checkpoint as ckpt
        self.ckpt, self.make = ckpt, make_processor
        self.ckdir = ckdir
        sp = make_processor()
        k = len(msgs) // 2
        for topic, data in msgs[:k]:
            sp.feed(topic, data)
        path = ckdir / "good.ckpt"
        ckpt.write(path, {"v1": ckpt.capture(sp, "v1")})
        self.good = path.read_bytes()
        self.rest = msgs[k:k + 100]
        self._fresh()

    def _fresh(self) -> None:
        import msgpack
        self.probe = self.make()
        self.before = msgpack.packb(self.ckpt.capture(self.probe, "v1"), use_bin_type=True)

    def case(self, seed: int, i: int) -> dict:
        import msgpack

        from perf.fuzz_cases import checkpoint_case
        data, what = checkpoint_case(seed, i, self.good)
        path = self.ckdir / "case.ckpt"
        path.write_bytes(data)
        out = {"i": i, "what": what[:80]}
        try:
            doc = self.ckpt.read(path)
            if "v1" not in doc["vehicles"]:
                raise self.ckpt.CheckpointError("foreign")
            self.ckpt.restore(self.probe, doc["vehicles"]["v1"])
        except self.ckpt.CheckpointError as exc:
            out["refused"] = 1
            out["one_line"] = int("\n" not in str(exc))
            after = msgpack.packb(self.ckpt.capture(self.probe, "v1"), use_bin_type=True)
            out["state_change"] = int(after != self.before)
            return out
        except Exception as exc:  # noqa: BLE001 - counted: must never happen
            out["internal"] = 1
            out["error"] = f"{type(exc).__name__}: {exc}"[:200]
            self._fresh()
            return out
        out["accepted"] = 1
        sp = self.probe
        used0 = sp.engine.counters["st1_used"] + sp.engine.counters["st2_used"]
        try:
            for topic, d in self.rest:
                sp.feed(topic, d)
            sp.end_stream(None)
        except Exception as exc:  # noqa: BLE001
            out["internal"] = 1
            out["error"] = f"feed: {type(exc).__name__}: {exc}"[:200]
        out["internal"] = out.get("internal", 0) + sp.rejected.get("internal_error", 0)
        out["frozen"] = int(sp.engine.counters["st1_used"] + sp.engine.counters["st2_used"] == used0)
        self._fresh()
        return out


def worker(kind: str, seed: int, start: int, stop: int, feed: int) -> None:
    """Run cases start..stop−1, one JSON line each on stdout."""
    work = Path(os.environ.get("FUZZ_DIR") or tempfile.mkdtemp(prefix="fuzz-cmd-"))
    msgs = _messages(_archive(work, seed))
    rig = CommandRig(msgs, work, feed) if kind == "commands" else CheckpointRig(msgs, work)
    print(json.dumps({"ready": True}), flush=True)
    for i in range(start, stop):
        print(json.dumps(rig.case(seed, i)), flush=True)
    if kind == "commands":
        rig.node.stop(drain_s=0.0, final_checkpoint=False)


# ------------------------------------------------------------------------------------ parent side
def run_kind(kind: str, n: int, seed: int, feed: int, work: str) -> dict:
    """All n cases of one kind through watched workers; the counts."""
    counts: Counter = Counter()
    examples: list[dict] = []
    i, t0 = 0, time.perf_counter()
    env = {**os.environ, "PYTHONPATH": str(ROOT), "FUZZ_DIR": work}
    while i < n:
        proc = subprocess.Popen([sys.executable, "-m", "perf.fuzz_commands", "--worker", kind,
                                 "--seed", str(seed), "--start", str(i), "--stop", str(n),
                                 "--feed", str(feed)], stdout=subprocess.PIPE, env=env, text=True)
        assert proc.stdout is not None
        limit = 600.0  # the first line waits for the kernels and the archive
        while i < n:
            ready, _, _ = select.select([proc.stdout], [], [], limit)
            line = proc.stdout.readline() if ready else None
            if line is None or line == "":
                counts["hangs" if line is None else "crashes"] += 1
                examples.append({"i": i, "kind": "hang" if line is None else "crash"})
                proc.kill()
                i += 1
                break
            limit = HANG_S
            res = json.loads(line)
            if "ready" in res:
                continue
            i = res["i"] + 1
            counts["cases"] += 1
            for k, v in res.items():
                if isinstance(v, int) and not isinstance(v, bool) and k != "i":
                    counts[k] += v
            if res.get("valid") is not None:
                counts["valid" if res["valid"] else "invalid"] += 1
            if any(res.get(k) for k in ("internal", "state_change", "accepted_invalid",
                                        "numeric_stuck", "hang", "refused_valid")) \
                    and len(examples) < 40:
                examples.append(res)
        proc.wait()
    counts["seconds"] = round(time.perf_counter() - t0, 1)
    return {"counts": dict(counts), "examples": examples}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--commands", type=int, default=10_000)
    p.add_argument("--checkpoints", type=int, default=1_000)
    p.add_argument("--seed", type=int, default=23)
    p.add_argument("--feed", type=int, default=4, help="input messages fed after every command")
    p.add_argument("--out", default=str(OUT))
    p.add_argument("--worker", choices=("commands", "checkpoints"), help=argparse.SUPPRESS)
    p.add_argument("--start", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--stop", type=int, default=0, help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.worker:
        worker(a.worker, a.seed, a.start, a.stop, a.feed)
        return 0
    with tempfile.TemporaryDirectory(prefix="fuzz-cmd-") as work:
        result = {"seed": a.seed, "feed": a.feed,
                  "commands": run_kind("commands", a.commands, a.seed, a.feed, work),
                  "checkpoints": run_kind("checkpoints", a.checkpoints, a.seed, a.feed, work)}
    bad = sum(result[k]["counts"].get(c, 0) for k in ("commands", "checkpoints")
              for c in ("crashes", "hangs", "internal", "state_change", "accepted_invalid",
                        "numeric_stuck"))
    result["failures"] = bad
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(result, indent=1))
    print(json.dumps({k: result[k]["counts"] for k in ("commands", "checkpoints")}, indent=1))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
