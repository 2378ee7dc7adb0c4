"""`make demo`: the whole system end to end on loopback, with no router or server to install.

1. synthesizes the 2006216 calibration (seeded; bus time starting at 1000 s) into an archive;
2. starts `radical node` and `radical record` as separate processes (Zenoh peers on 127.0.0.1);
3. replays the archive with `radical replay --fast` (nothing dropped: blocking congestion control);
4. asks the node for the end-of-stream summary over its command queryable, stops the node and the
   recorder cleanly (SIGINT), writes the summary file and `radical report` of the recording;
5. prints the paper-style table (estimate ± 1σ, truth, error/σ) and where everything is.

Usage: ``python -m mission.demo [--out DIR] [--duration S] [--seed N] [--port P]``.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import msgpack

from radical_rt.apps.batch import summary_table
from radical_rt.io.outpaths import output_dir

VEHICLE = "messenger"


def _radical(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "radical_rt.apps.cli", *args], **kw)


def _wait_line(proc: subprocess.Popen, needle: str, timeout: float, what: str) -> None:
    """Read the process's stderr until a line containing needle appears (echoing it)."""
    deadline = time.monotonic() + timeout
    assert proc.stderr is not None
    while time.monotonic() < deadline:
        line = proc.stderr.readline()
        if not line:
            if proc.poll() is not None:
                raise RuntimeError(f"{what} exited with code {proc.returncode}")
            continue
        print(f"  [{what}] {line.rstrip()}", flush=True)
        if needle in line:
            return
    raise RuntimeError(f"{what} not ready after {timeout:.0f} s")


def _command(session, cmd: dict) -> dict | None:
    for r in session.get(f"radical/{VEHICLE}/cmd", payload=msgpack.packb(cmd), timeout=60.0):
        if r.ok:
            return msgpack.unpackb(r.ok.payload.to_bytes(), raw=False)
    return None


def _end_stream(endpoint: str, timeout: float = 600.0) -> dict:
    """Wait until the node has fed every received message, then ask for its end-of-stream
    summary (command queryable; `end_stream` is a documented extension of CONTRACT §3.2)."""
    import zenoh

    from radical_rt.io.zconfig import make_config

    with zenoh.open(make_config("peer", connect=[endpoint])) as s:
        deadline, last = time.monotonic() + timeout, None
        while time.monotonic() < deadline:
            st = _command(s, {"cmd": "status"})
            if st is not None:
                info = st["node"]
                now = (sum(info["received"].values()), sum(info["fed"].values()))
                if info["queue_depth"] == 0 and now[0] == now[1] and now == last:
                    reply = _command(s, {"cmd": "end_stream", "next": "none"})
                    if reply is not None:
                        return reply
                last = now
            time.sleep(0.5)
    raise RuntimeError("the node did not drain its input or answer end_stream in time")


def _truth(sim: Path) -> dict | None:
    from radical_rt.apps.batch import truth_paper_units
    from radical_rt.io.archive import ArchiveReader
    last = None
    with ArchiveReader(str(sim)) as r:
        for _t, _ns, msg in r.iter_messages(topics=["/truth/params"]):
            last = msg
    return truth_paper_units(last) if last else None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="radical-demo", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="out", type=output_dir, help="output directory (default: out)")
    ap.add_argument("--duration", type=float, default=None, help="seconds (default: 7200)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--port", type=int, default=None, help="node port (default: a free one)")
    args = ap.parse_args(argv)
    from radical_rt.io.zconfig import free_port
    from replayer.synth.api import synthesize

    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    sim, rec, summ, rep = out / "2006216.mcap", out / "recording.mcap", out / "summary.json", out / "report"
    toml = out / "2006216_demo.toml"
    toml.write_text('base = "2006216"\nt_start_s = 1000.0\n')
    ep = f"tcp/127.0.0.1:{args.port or free_port()}"
    t0 = time.monotonic()
    print("note: the first run compiles the Numba kernels (about a minute, in the synthesizer and "
          "the node); later runs load them from the cache", flush=True)
    print(f"[1/5] synthesizing scenario 2006216 (seed {args.seed}) → {sim}", flush=True)
    synthesize(str(toml), sim, seed=args.seed, duration=args.duration, progress=True)
    print(f"[2/5] starting radical node and radical record on {ep}", flush=True)
    node = _radical("node", "--vehicle", VEHICLE, "--listen", ep, "--checkpoint", str(out / "node.ckpt"),
                    stderr=subprocess.PIPE, text=True)
    procs = [node]
    try:
        _wait_line(node, "ready", 300, "node")
        recorder = _radical("record", "-o", str(rec), "--vehicle", VEHICLE, "--connect", ep,
                            stderr=subprocess.PIPE, text=True)
        procs.append(recorder)
        _wait_line(recorder, "", 60, "record")
        print("[3/5] replaying the archive at --fast", flush=True)
        rc = subprocess.call([sys.executable, "-m", "radical_rt.apps.cli", "replay", str(sim), "--vehicle",
                              VEHICLE, "--fast", "--connect", ep, "--wait-node", "60"])
        if rc != 0:
            raise RuntimeError(f"radical replay failed with code {rc}")
        print("[4/5] end of stream: summary from the node, stopping node and recorder", flush=True)
        reply = _end_stream(ep)
        time.sleep(1.0)  # let the recorder take the last packets
    finally:
        for p in reversed(procs):
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        for p in reversed(procs):
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
    summary = reply.get("summary", reply)
    truth = _truth(sim)
    if truth:
        summary["truth"] = truth
    summ.write_text(json.dumps(summary, indent=1) + "\n")
    print(f"[5/5] report of the recording → {rep}", flush=True)
    subprocess.call([sys.executable, "-m", "radical_rt.apps.cli", "report", str(rec), "-o", str(rep)])
    print()
    print(summary_table(summary))
    c = summary["counters"]
    print(f"mode: {summary.get('mode')}; SIRU samples {c['siru_samples']} (repeated "
          f"{c['siru_repeated']}, missing {c['siru_missing']}); ST1 used {c['st1_used']}, "
          f"ST2 used {c['st2_used']}; rejected {c['input_rejected']}")
    print(f"demo finished in {time.monotonic() - t0:.0f} s")
    print(f"input archive: {sim}\nrecording:     {rec}\nsummary:       {summ}\nreport:        {rep}/index.html")
    return 0


if __name__ == "__main__":
    sys.exit(main())
