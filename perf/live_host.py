"""The live benches' processes on this host: the CPU set every process is pinned to
(:func:`default_cpus`, :func:`pinned`), how children are launched (:func:`radical_argv`,
:func:`child_env`), their RSS and CPU time (:func:`proc_stat`), stopping them
(:func:`stop_process`), the machine description of the results (:func:`machine_info`) and the
harness's error (:class:`LiveError`). The harness itself: :mod:`perf.live`.
"""

from __future__ import annotations

import os
import platform
import shutil
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent


class LiveError(RuntimeError):
    """A live run could not be completed (a process failed, a time-out)."""


def default_cpus() -> list[int]:
    """The first two CPUs this process may run on (the whole machine on a 2-vCPU host)."""
    try:
        return sorted(os.sched_getaffinity(0))[:2]
    except AttributeError:  # pragma: no cover - not Linux
        return []


def pinned(argv: list[str], cpus: list[int]) -> list[str]:
    """argv prefixed with ``taskset -c CPUS`` (exec'd, so the pid is the program's own)."""
    if cpus and shutil.which("taskset"):
        return ["taskset", "-c", ",".join(map(str, cpus)), *argv]
    return argv


def radical_argv() -> list[str]:
    """How to launch ``radical`` from this interpreter (the venv's console script if present)."""
    script = Path(sys.executable).with_name("radical")
    return [str(script)] if script.exists() else [sys.executable, "-m", "radical_rt.apps.cli"]


def child_env(extra: dict[str, str] | None = None) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.setdefault("PYTHONUNBUFFERED", "1")
    env.update(extra or {})
    return env


def proc_stat(pid: int) -> tuple[int, float] | None:
    """(RSS in kB, CPU seconds user+system) of a process, or None if it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            rss = next(int(line.split()[1]) for line in f if line.startswith("VmRSS:"))
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        ticks = os.sysconf("SC_CLK_TCK")
        return rss, (int(fields[11]) + int(fields[12])) / ticks
    except (OSError, StopIteration, ValueError, IndexError):
        return None


def stop_process(p: subprocess.Popen, sig: int = signal.SIGINT, timeout: float = 20.0) -> int | None:
    """Signal one process we started (by its pid), wait, then kill it if it does not exit."""
    if p.poll() is None:
        try:
            p.send_signal(sig)
            return p.wait(timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(5)
    return p.returncode

def machine_info() -> dict[str, Any]:
    """CPU model and count, load average and package versions (for the results table)."""
    info: dict[str, Any] = {"python": platform.python_version(), "platform": platform.platform(),
                            "cpus_online": os.cpu_count()}
    try:
        info["cpus_allowed"] = sorted(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover
        pass
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                info["cpu_model"] = line.split(":", 1)[1].strip()
                break
    except OSError:  # pragma: no cover
        pass
    try:
        info["loadavg"] = [float(x) for x in open("/proc/loadavg").read().split()[:3]]
    except OSError:  # pragma: no cover
        pass
    from importlib.metadata import PackageNotFoundError, version
    for pkg in ("numba", "llvmlite", "numpy", "eclipse-zenoh", "msgpack"):
        try:
            info[pkg] = version(pkg)
        except PackageNotFoundError:  # pragma: no cover
            info[pkg] = None
    return info
