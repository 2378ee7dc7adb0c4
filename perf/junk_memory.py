"""Memory of a `radical node` under oversized junk input (issue 23, "Memory").

    python -m perf.junk_memory [--count 300] [--mb 9] [--json OUT.json]

Starts `radical node` (subprocess, loopback, free port), reads its RSS (/proc/PID/status) once
it is ready, publishes ``--count`` junk payloads of ``--mb`` MB on ``radical/<V>/siru`` (BLOCK),
(``--kind array``: a msgpack array of zeros, which decodes into millions of objects;
``random``: random bytes), then one valid temp message, waits until the node has taken everything, and reads the RSS again
and the node's counters (status command). Prints one JSON map: rss before/peak/after (MB), the
rejections, the wall time.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgpack

ROOT = Path(__file__).resolve().parents[1]


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def _status(client) -> dict:
    """The node's status (retried: a fresh session may not know the route yet)."""
    for _ in range(200):
        r = client.get("radical/jm/cmd", msgpack.packb({"cmd": "status"}), timeout=10)
        if r:
            return msgpack.unpackb(r[0], raw=False, strict_map_key=False)
        time.sleep(0.05)
    raise RuntimeError("no status reply")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m perf.junk_memory")
    ap.add_argument("--count", type=int, default=300)
    ap.add_argument("--mb", type=float, default=9.0)
    ap.add_argument("--kind", choices=("array", "random"), default="array",
                    help="array: a msgpack array32 of zeros (decodes into millions of objects); "
                         "random: random bytes")
    ap.add_argument("--json", metavar="OUT.json")
    a = ap.parse_args(argv)
    from radical_rt.io import zconfig
    from radical_rt.io.zenoh_transport import ZenohTransport

    ep = f"tcp/127.0.0.1:{zconfig.free_port()}"
    log = open(os.devnull, "w")
    node = subprocess.Popen([sys.executable, "-m", "radical_rt.apps.cli", "node", "--vehicle", "jm",
                             "--listen", ep], stdout=log, stderr=subprocess.PIPE, text=True,
                            cwd=ROOT, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        while "ready" not in (node.stderr.readline() or "ready"):
            pass
        threading.Thread(target=lambda: [None for _ in node.stderr], daemon=True).start()
        client = ZenohTransport("peer", connect=[ep])
        st = _status(client)
        rss0 = peak = _rss_mb(node.pid)
        n = int(a.mb * 1e6) - 5
        junk = (b"\xdd" + n.to_bytes(4, "big") + b"\x00" * n) if a.kind == "array" \
            else os.urandom(n + 5)
        t0 = time.monotonic()
        for _ in range(a.count):
            client.put("radical/jm/siru", junk, block=True)
            peak = max(peak, _rss_mb(node.pid))
        client.put("radical/jm/temp", msgpack.packb({"v": 1, "t_bus": 1.0, "siru_C": 20.0}),
                   block=True)
        while True:
            st = _status(client)
            peak = max(peak, _rss_mb(node.pid))
            if st["node"]["received"].get("temp") == 1:
                break
            time.sleep(0.05)
        wall = time.monotonic() - t0
        time.sleep(1.0)
        res = {"count": a.count, "payload_mb": a.mb, "kind": a.kind, "rss_ready_mb": rss0, "rss_peak_mb": peak,
               "rss_after_mb": _rss_mb(node.pid), "rejected": st["rejected"],
               "received": st["node"]["received"], "wall_s": wall}
        client.close()
    finally:
        node.terminate()
        node.wait(30)
    print(json.dumps(res, indent=1, sort_keys=True))
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=1, sort_keys=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
