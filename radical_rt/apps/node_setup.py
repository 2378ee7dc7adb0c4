"""Setting up the node's vehicles before it serves them: one StreamProcessor per vehicle, restored
from a checkpoint when resuming (:func:`build_processors`), and every Numba kernel compiled or
loaded beforehand on a throwaway engine (:func:`warm_up`), so that the first message never waits
for the JIT. The node itself is :class:`radical_rt.apps.node.FilterNode`.
"""

from __future__ import annotations

import logging
import math
import time

from radical_rt.apps.batch import make_processor
from radical_rt.apps.node_vehicle import VEHICLE_RE, packb
from radical_rt.contract.params import ParamTable
from radical_rt.io import checkpoint as ckpt
from radical_rt.stream.processor import StreamProcessor

log = logging.getLogger("radical.node")


def build_processors(vehicles: list[str], config: str | None = None, packets: str | None = None,
                     clock_mode: str = "reconstruct", resume: str | None = None,
                     resume_bump: bool = False, force_vehicle: bool = False,
                     resume_new_stream: bool = False) -> dict[str, StreamProcessor]:
    """One StreamProcessor per vehicle (own parameter table and packets), restored if resuming.

    Resuming needs the state of every served vehicle in the checkpoint; a checkpoint of another
    vehicle is refused unless ``force_vehicle`` (then a single-vehicle checkpoint is loaded into
    a single served vehicle, and served vehicles the file does not hold start cold). Raises
    ParamError / PacketError / CheckpointError / ValueError with one-line messages.
    """
    if not vehicles:
        raise ValueError("give at least one --vehicle")
    for name in vehicles:
        if not VEHICLE_RE.match(name):
            raise ValueError(f"vehicle name {name!r} must match [a-z0-9_-]+")
    if len(set(vehicles)) != len(vehicles):
        raise ValueError(f"vehicle names repeat: {vehicles}")
    out = {}
    for name in vehicles:
        table = ParamTable.from_toml(config) if config else ParamTable()
        out[name] = make_processor(table, clock_mode, packets)
    if resume:
        doc = ckpt.read(resume)
        held = sorted(doc["vehicles"])
        for name, sp in out.items():
            key = name
            if name not in doc["vehicles"]:
                if not force_vehicle:
                    raise ckpt.CheckpointError(
                        f"{resume}: checkpoint of vehicle(s) {held}, not of {name!r} (refused; "
                        "--force-vehicle overrides)")
                if len(held) == 1 and len(out) == 1:
                    key = held[0]
                    log.warning("%s: loading the state of vehicle %r (--force-vehicle)", name, key)
                else:
                    log.warning("checkpoint %s has no state for vehicle %r: it starts cold "
                                "(--force-vehicle)", resume, name)
                    continue
            state = doc["vehicles"][key]
            try:
                ckpt.restore(sp, state, bump=resume_bump, new_stream=resume_new_stream)
            except ckpt.CheckpointError as exc:
                raise ckpt.CheckpointError(f"{resume}: vehicle {key}: {exc}") from None
            log.info("%s: resumed from %s (t=%.3f, mode before restart %s)", name, resume,
                     state.get("t", math.nan), state.get("mode"))
        extra = sorted(set(held) - set(vehicles))
        if extra and not force_vehicle:
            log.warning("checkpoint %s also holds %s (not served, ignored)", resume, extra)
    return out


def warm_up(clock_mode: str = "reconstruct", seconds: float = 2.0) -> float:
    """Compile/load every Numba kernel on a throwaway engine fed a tiny synthetic stream.

    A stationary vehicle, body = inertial: SIRU batches of 10 zero increments at 100 Hz, both
    trackers at 10 Hz, a throw-away FDI hypothesis bank over it, then a warm start with both
    bump modes and a cold start. Returns seconds.
    """
    t0 = time.perf_counter()
    sp = make_processor(ParamTable(), clock_mode)
    q_st1 = [1.0, 0.0, 0.0, 0.0]  # R_st1_from_body = diag(1, -1, -1)
    q_st2 = [math.sqrt(0.5), -math.sqrt(0.5), 0.0, 0.0]  # R_st2_from_body_nom
    n = sp.engine.n_gyro
    for b in range(int(seconds * 10)):
        k0 = b * 10
        t = [1.0 + 0.01 * (k0 + i) for i in range(1, 11)]
        sp.feed("siru", packb({"v": 1, "t_bus": t, "tt": [(k0 + i) * 10000 for i in range(1, 11)],
                               "dtheta": [[0.0] * n for _ in range(10)], "status": [0] * 10}))
        for topic, q in (("st1", q_st1), ("st2", q_st2)):
            sp.feed(topic, packb({"v": 1, "t_bus": t[-1], "q": q, "n_stars": 9, "valid": True}))
    if sp.engine.fdi is not None:  # the FDI bank's kernels (they run only during an alarm)
        sp.engine.fdi.compile_bank(sp.engine)
    sp.end_stream("warm")
    e = sp.engine
    e.bump({g: list(v) for g, v in e.si.bump_sigma.items()}, "scale")
    e.cold_start()
    ckpt.capture(sp, "warm-up")
    return time.perf_counter() - t0
