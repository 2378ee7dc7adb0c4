"""What a checkpoint carries so that a resumed node continues the stream (issue 23 part A).

:func:`capture` takes one vehicle's complete running state: the engine's estimates and UD factors
plus everything between two events (time-update and parity accumulators, pending parameter
noise, the queued lagged parity sums, the lock latch), the SIRU clock's full state (phase and
lock included), the samples held back for reordering (gyro and tracker queues), the packet
schedules and the FDI outcome and running state (history, snapshots, alarm, bank:
:mod:`radical_rt.io.ckpt_fdi`). :func:`check` validates every field of such a state against the
node's own processor and returns a :class:`Plan` — nothing is touched — and :func:`apply` puts a
checked plan into the processor. Field errors are :class:`~radical_rt.io.ckpt_validate.
CheckpointFieldError` naming the field.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from radical_rt.clock import clock_layout as L
from radical_rt.contract.flags import Flag
from radical_rt.io import ckpt_fdi
from radical_rt.io import ckpt_validate as cv
from radical_rt.stream.processor import StreamProcessor
from radical_rt.stream.siru_wire import SS_WINDOW
from radical_rt.stream.tracker_queue import SI_END, SI_HEAD, SI_LATE, SI_SEQ

MODES = ("init", "converging", "converged", "degraded")
FDI_STATES = ("waiting", "monitoring", "alarm", "three-gyro", "flagged", "disabled")
T_MAX = 1e12  # |time| [s] of any stored time (bus time line)
#: engine arrays: name → (lo, hi) of every element (SI); shapes come from the engine itself
ENGINE_ARRAYS = {"q": (-1.0, 1.0), "xp": (-10.0, 10.0), "U": (-1e12, 1e12), "d": (0.0, 1e12),
                 "N": (-1.0 - 1e-9, 1.0 + 1e-9), "omega": (-100.0, 100.0), "excluded": (0, 1),
                 "acc_i": (0, cv.INT_MAX), "acc_f": (-1e9, 1e9), "th_acc": (-1e3, 1e3),
                 "q_dt": (0.0, 1e6), "Phi_aa": (-1e6, 1e6), "Phi_ap": (-1e9, 1e9),
                 "Q_aa": (-1e6, 1e6), "par_y": (-1e9, 1e9), "par_t": (-1e12, 1e12),
                 "kappa_last": (0.0, 1.0)}
_NUMERIC = int(Flag.NUMERIC)


def _arr(a: np.ndarray) -> dict[str, Any]:
    a = np.ascontiguousarray(a)
    return {"dtype": a.dtype.str, "shape": list(a.shape), "data": a.tobytes()}


# ------------------------------------------------------------------------------------ capture
def capture(sp: StreamProcessor, history: bool = True) -> dict[str, Any]:
    """The running state of one vehicle's processor (engine, clock, queues, FDI; msgpack-able).
    Call it from the thread that runs ``sp``."""
    e, gq, tq = sp.engine, sp.gyro_q, sp.tracker_q
    h, z = gq.head, gq.end
    th, tz = int(tq.si[SI_HEAD]), int(tq.si[SI_END])
    fdi = e.fdi
    return {
        "engine": {
            "arrays": {k: _arr(getattr(e, k)) for k in ENGINE_ARRAYS},
            "flags": int(e.flags), "mode": e.mode, "t": float(e.t), "att_valid": bool(e.att_valid),
            "masked": bool(e.masked), "locked_since": float(e.locked_since),
            "counters": {str(k): int(v) for k, v in e.counters.items()},
            "nis_sum": {str(k): float(v) for k, v in e.nis_sum.items()},
            "last_valid_st": {str(k): float(v) for k, v in e.last_valid_st.items()},
            "parity_queue": [[float(t), _arr(y), _arr(tt), float(nz)]
                             for t, y, tt, nz in e.parity_queue]},
        "clock": sp.clock.get_state(),
        "queues": {"gyro": {k: _arr(a[h:z]) for k, a in
                            zip(("t", "dt", "dtheta", "status", "bridged", "var_extra"),
                                gq.arrays(), strict=True)},
                   "tracker": {"ss": _arr(tq.ss), "si": _arr(tq.si), "ev_f": _arr(tq.ev_f[th:tz]),
                               "ev_i": _arr(tq.ev_i[th:tz])},
                   "last_t": {str(k): float(v) for k, v in sp.last_t.items()},
                   "t_now": float(sp.t_now)},
        "schedule": {"packets": {n: {"next_t": float(s.next_t), "windows": int(s.windows)}
                                 for n, s in sp.packets.items()},
                     "diag_next_t": float(sp.diag.next_t),
                     "last_reject_t": float(sp.last_reject_t)},
        "fdi": None if fdi is None else {
            "state": fdi.state, "failed": sorted(int(g) for g in fdi.failed_by_fdi),
            "flagged_only": sorted(int(g) for g in fdi.flagged_only),
            "counts": {str(k): int(v) for k, v in fdi.counts.items()},
            "monitor": ckpt_fdi.capture(fdi, history)},
    }


# ------------------------------------------------------------------------------------ check
@dataclass
class Plan:
    """A validated running state, ready for :func:`apply`."""

    engine_arrays: dict[str, np.ndarray]
    engine: dict[str, Any]
    parity_queue: list[tuple[float, np.ndarray, np.ndarray, float]]
    clock: dict[str, Any]
    gyro: dict[str, np.ndarray]
    tracker: dict[str, np.ndarray]
    stream: dict[str, Any]
    fdi: dict[str, Any] | None = None
    schedule: dict[str, Any] = field(default_factory=dict)


def check(state: Any, sp: StreamProcessor) -> Plan:
    """Validate a :func:`capture` state against ``sp`` (same geometry and clock configuration);
    CheckpointFieldError naming the first bad field. ``sp`` is not changed."""
    e = sp.engine
    n = e.n_gyro
    eng = cv.need(state, "engine", "state")
    arrs = cv.need(eng, "arrays", "engine")
    a = {}
    for k, (lo, hi) in ENGINE_ARRAYS.items():
        ref = getattr(e, k)
        a[k] = cv.array(cv.need(arrs, k, "engine.arrays"), f"engine.{k}", ref.dtype.str,
                        ref.shape, lo, hi)
    cv.unit_quaternion(a["q"], "engine.q")
    cv.unit_upper(a["U"], "engine.U")
    if not (a["d"] > 0).all():
        raise cv.CheckpointFieldError("engine.d: the UD diagonal must be > 0")
    if int(a["excluded"].sum()) > n - 3:
        raise cv.CheckpointFieldError(f"engine.excluded: at least 3 of the {n} gyros must stay "
                                      "included")
    if not (a["acc_i"][0] <= 1000 and a["acc_i"][1] <= 100_000):
        raise cv.CheckpointFieldError("engine.acc_i: window counts beyond the largest windows")
    s: dict[str, Any] = {
        "flags": cv.number(cv.need(eng, "flags", "engine"), "engine.flags", 0, 2**31 - 1,
                           integer=True),
        "mode": cv.choice(cv.need(eng, "mode", "engine"), "engine.mode", MODES),
        "t": cv.number(cv.need(eng, "t", "engine"), "engine.t", -math.inf, T_MAX, finite=False),
        "att_valid": cv.boolean(cv.need(eng, "att_valid", "engine"), "engine.att_valid"),
        "masked": cv.boolean(cv.need(eng, "masked", "engine"), "engine.masked"),
        "locked_since": cv.number(cv.need(eng, "locked_since", "engine"), "engine.locked_since",
                                  -T_MAX, math.inf, finite=False),
        "counters": cv.counter_map(cv.need(eng, "counters", "engine"), "engine.counters"),
        "nis_sum": cv.counter_map(cv.need(eng, "nis_sum", "engine"), "engine.nis_sum", floats=True),
    }
    lv = cv.need(eng, "last_valid_st", "engine")
    if not isinstance(lv, dict) or not set(lv) <= {"1", "2"}:
        raise cv.CheckpointFieldError("engine.last_valid_st: expected a map with keys '1', '2'")
    s["last_valid_st"] = {int(k): cv.number(v, f"engine.last_valid_st.{k}", -T_MAX, T_MAX)
                          for k, v in lv.items()}
    if s["att_valid"] and not math.isfinite(s["t"]):
        raise cv.CheckpointFieldError("engine.t: must be finite once the attitude is valid")
    pq = cv.need(eng, "parity_queue", "engine")
    if not isinstance(pq, list) or len(pq) > cv.MAX_ROWS:
        raise cv.CheckpointFieldError("engine.parity_queue: expected a list of parity sums")
    queue = []
    for i, row in enumerate(pq):
        w = f"engine.parity_queue[{i}]"
        if not isinstance(row, list) or len(row) != 4:
            raise cv.CheckpointFieldError(f"{w}: expected [t, par_y, par_t, noise]")
        queue.append((cv.number(row[0], w + ".t", -T_MAX, T_MAX),
                      cv.array(row[1], w + ".par_y", "<f8", (2, n), -1e9, 1e9),
                      cv.array(row[2], w + ".par_t", "<f8", (2, n), -1e12, 1e12),
                      cv.number(row[3], w + ".noise", 0.0, 1e6)))
    plan = Plan(a, s, queue, _check_clock(cv.need(state, "clock", "state"), sp), {}, {}, {})
    _check_queues(cv.need(state, "queues", "state"), sp, plan)
    plan.schedule = _check_schedule(cv.need(state, "schedule", "state"), sp)
    plan.fdi = _check_fdi(state.get("fdi"), n, sp)
    return plan


def _check_clock(c: Any, sp: StreamProcessor) -> dict[str, Any]:
    """The clock state must be of the node's configuration; its int and float arrays in range
    (indices, flags, counts, no NaN), then it is a valid :meth:`SiruClock.set_state` input."""
    clock = sp.clock
    if cv.need(c, "config", "clock") != asdict(clock.config):
        raise cv.CheckpointFieldError("clock.config: differs from this node's clock configuration")
    if cv.need(c, "n_gyro", "clock") != clock.n_gyro or cv.need(c, "schema", "clock") != \
            clock.get_state()["schema"]:
        raise cv.CheckpointFieldError("clock: schema or gyro count differs from this node's")
    ist = cv.num_list(cv.need(c, "I", "clock"), "clock.I", L.NI, -cv.INT_MAX, cv.INT_MAX,
                      integer=True)
    fst = cv.num_list(cv.need(c, "F", "clock"), "clock.F", L.f_size(clock.n_gyro), finite=False)
    for k in (L.I_HAVE_A, L.I_HAVE_P, L.I_ACQ, L.I_HAVE_OUT, L.I_GRID, L.I_SP_ON, L.I_KAL,
              L.I_KMEM):
        cv.number(int(ist[k]), f"clock.I[{k}]", 0, 1, integer=True)
    cv.number(int(ist[L.I_NV]), f"clock.I[{L.I_NV}] (polygon vertices)", 0, (L.VMAX - 4) // 2,
              integer=True)
    if int(ist[L.I_NG]) != clock.n_gyro:
        raise cv.CheckpointFieldError(f"clock.I[{L.I_NG}]: gyro count differs")
    cv.values(ist[L.C0:], "clock.I (counters)", 0, cv.INT_MAX)
    cv.values(ist[L.I_CONSEC_REJ:L.I_CONSEC_REJ + 1], "clock.I (rejected reads)", 0, cv.INT_MAX)
    ref = np.asarray(clock.get_state()["F"], np.float64)
    if not np.array_equal(fst[:L.NPRM], ref[:L.NPRM]):
        raise cv.CheckpointFieldError("clock.F: parameters differ from this node's configuration")
    cv.values(fst[L.NPRM:L.OX], "clock.F (state)", -T_MAX, T_MAX, finite=False)
    nv = int(ist[L.I_NV])
    for off, name in ((L.OX, "polygon x"), (L.OY, "polygon y")):
        cv.values(fst[off:off + nv], f"clock.F ({name})", -1e6, 1e6)
    cv.values(fst[L.DA:], "clock.F (held increments)", -10.0, 10.0)
    if not fst[L.F_Y_LO] <= fst[L.F_Y_HI]:
        raise cv.CheckpointFieldError("clock.F: slope range is empty")
    for k, name in ((L.F_KCXX, "fine line var x"), (L.F_KCYY, "fine line var y")):
        cv.number(float(fst[k]), f"clock.F[{k}] ({name})", 0.0, 1.0)
    return {"schema": c["schema"], "config": c["config"], "n_gyro": clock.n_gyro,
            "I": [int(v) for v in ist], "F": [float(v) for v in fst]}


def _check_queues(qd: Any, sp: StreamProcessor, plan: Plan) -> None:
    n = sp.engine.n_gyro
    g = cv.need(qd, "gyro", "queues")
    m = cv.need(cv.need(g, "t", "queues.gyro"), "shape", "queues.gyro.t")
    if not (isinstance(m, list) and len(m) == 1 and isinstance(m[0], int)
            and 0 <= m[0] <= cv.MAX_ROWS):
        raise cv.CheckpointFieldError("queues.gyro.t: expected at most 100000 samples")
    m = m[0]
    spec = {"t": ("<f8", (m,), -T_MAX, T_MAX), "dt": ("<f8", (m,), 0.0, 1e6),
            "dtheta": ("<f8", (m, n), -10.0, 10.0), "status": ("<i8", (m,), 0, 2**31 - 1),
            "bridged": ("|b1", (m,), 0, 1), "var_extra": ("<f8", (m,), 0.0, 1.0)}
    plan.gyro = {k: cv.array(cv.need(g, k, "queues.gyro"), f"queues.gyro.{k}", *v)
                 for k, v in spec.items()}
    if m > 1 and not (np.diff(plan.gyro["t"]) >= 0).all():
        raise cv.CheckpointFieldError("queues.gyro.t: samples must be in time order")
    tr = cv.need(qd, "tracker", "queues")
    ss = cv.array(cv.need(tr, "ss", "queues.tracker"), "queues.tracker.ss", "<f8",
                  (len(sp.tracker_q.ss),), -T_MAX, T_MAX, finite=False)
    si = cv.array(cv.need(tr, "si", "queues.tracker"), "queues.tracker.si", "<i8", (4,),
                  0, cv.INT_MAX)
    r = cv.need(cv.need(tr, "ev_f", "queues.tracker"), "shape", "queues.tracker.ev_f")
    if not (isinstance(r, list) and len(r) == 2 and isinstance(r[0], int)
            and 0 <= r[0] <= cv.MAX_ROWS):
        raise cv.CheckpointFieldError("queues.tracker.ev_f: expected at most 100000 rows")
    ev_f = cv.array(tr["ev_f"], "queues.tracker.ev_f", "<f8", (r[0], 5), -T_MAX, T_MAX)
    ev_i = cv.array(cv.need(tr, "ev_i", "queues.tracker"), "queues.tracker.ev_i", "<i8",
                    (r[0], 4), 0, cv.INT_MAX)
    if r[0]:
        cv.values(ev_i[:, 0], "queues.tracker.ev_i (tracker)", 1, 2)
        cv.values(ev_i[:, 1], "queues.tracker.ev_i (n_stars)", 0, 2**31 - 1)
        cv.values(ev_i[:, 2], "queues.tracker.ev_i (valid)", 0, 1)
        cv.values(ev_f[:, 1:5], "queues.tracker.ev_f (q)", -1.0, 1.0)
    plan.tracker = {"ss": ss, "si": si, "ev_f": ev_f, "ev_i": ev_i}
    lt = cv.need(qd, "last_t", "queues")
    if not isinstance(lt, dict) or not set(lt) <= {"temp"}:
        raise cv.CheckpointFieldError("queues.last_t: expected a map with key 'temp'")
    plan.stream = {"last_t": {k: cv.number(v, f"queues.last_t.{k}", -T_MAX, T_MAX)
                              for k, v in lt.items()},
                   "t_now": cv.number(cv.need(qd, "t_now", "queues"), "queues.t_now",
                                      -math.inf, T_MAX, finite=False)}


def _check_schedule(sd: Any, sp: StreamProcessor) -> dict[str, Any]:
    pk = cv.need(sd, "packets", "schedule")
    if not isinstance(pk, dict) or len(pk) > 8:
        raise cv.CheckpointFieldError("schedule.packets: expected a map per packet")
    out: dict[str, Any] = {"packets": {}}
    for name, p in pk.items():
        w = f"schedule.packets.{str(name)[:20]}"
        out["packets"][name] = (
            cv.number(cv.need(p, "next_t", w), w + ".next_t", -math.inf, T_MAX, finite=False),
            cv.number(cv.need(p, "windows", w), w + ".windows", 0, 1_000_000, integer=True))
    out["diag_next_t"] = cv.number(cv.need(sd, "diag_next_t", "schedule"), "schedule.diag_next_t",
                                   -math.inf, T_MAX, finite=False)
    out["last_reject_t"] = cv.number(cv.need(sd, "last_reject_t", "schedule"),
                                     "schedule.last_reject_t", -math.inf, T_MAX, finite=False)
    return out


def _check_fdi(f: Any, n: int, sp: StreamProcessor) -> dict[str, Any] | None:
    """The FDI outcome, and the monitor's running state where the checkpoint has it
    (:mod:`radical_rt.io.ckpt_fdi`; checkpoints written before it carry the outcome only)."""
    if f is None:
        return None
    monitor = None
    if isinstance(f, dict) and f.get("monitor") is not None and sp.engine.fdi is not None:
        monitor = ckpt_fdi.check(f["monitor"], sp)
    st = cv.choice(cv.need(f, "state", "fdi"), "fdi.state", FDI_STATES)
    failed = cv.num_list(cv.need(f, "failed", "fdi"), "fdi.failed", None, 0, n - 1, integer=True)
    only = cv.num_list(cv.need(f, "flagged_only", "fdi"), "fdi.flagged_only", None, 0, n - 1,
                       integer=True)
    return {"state": st, "failed": {int(g) for g in failed}, "flagged_only": {int(g) for g in only},
            "counts": cv.counter_map(cv.need(f, "counts", "fdi"), "fdi.counts"),
            "monitor": monitor}


# ------------------------------------------------------------------------------------ apply
def apply(sp: StreamProcessor, plan: Plan) -> None:
    """Put a checked plan into ``sp`` (the processor then continues the captured stream)."""
    e, gq, tq = sp.engine, sp.gyro_q, sp.tracker_q
    for k, v in plan.engine_arrays.items():
        getattr(e, k)[...] = v
    s = plan.engine
    e.flags = s["flags"] & ~_NUMERIC  # the factors were validated: no numeric fault stays latched
    e.mode, e.t, e.att_valid, e.masked = s["mode"], s["t"], s["att_valid"], s["masked"]
    if e.mode == "degraded" and not e.excluded.any():
        e.mode = "converging"  # update_mode decides again at the next window
    e.locked_since = s["locked_since"]
    e.counters.clear()
    e.counters.update(s["counters"])
    e.nis_sum.clear()
    e.nis_sum.update(s["nis_sum"])
    e.last_valid_st = dict(s["last_valid_st"])
    e.set_parity_queue(plan.parity_queue)
    e.dx[:] = 0.0
    e.state_restored()
    sp.clock.set_state(plan.clock)
    g = plan.gyro
    m = len(g["t"])
    gq.clear()
    gq.reserve(m)
    for dst, k in zip(gq.arrays(), ("t", "dt", "dtheta", "status", "bridged", "var_extra"),
                      strict=True):
        dst[:m] = g[k]
    gq.end = m
    t = plan.tracker
    r = len(t["ev_f"])
    while tq.ev_f.shape[0] < r + 1:
        tq.grow()
    window = tq.ss[SS_WINDOW]  # configuration of this node, not state
    tq.ss[:] = t["ss"]
    tq.ss[SS_WINDOW] = window
    tq.si[SI_LATE], tq.si[SI_SEQ] = t["si"][SI_LATE], t["si"][SI_SEQ]
    tq.ev_f[:r], tq.ev_i[:r] = t["ev_f"], t["ev_i"]
    tq.si[SI_HEAD], tq.si[SI_END] = 0, r
    sp.last_t = dict(plan.stream["last_t"])
    sp.t_now = plan.stream["t_now"]
    sch = plan.schedule
    for name, (next_t, windows) in sch.get("packets", {}).items():
        if name in sp.packets:
            sp.packets[name].next_t, sp.packets[name].windows = next_t, windows
    sp.diag.next_t = sch.get("diag_next_t", -math.inf)
    sp.last_reject_t = sch.get("last_reject_t", -math.inf)
    sp.packet_wake = None
    f = plan.fdi
    if f is not None and e.fdi is not None and f.get("monitor") is not None:
        e.fdi.set_state(e, f["monitor"])  # history, snapshots, alarm and bank: it continues
    elif f is not None and e.fdi is not None:
        # an older checkpoint without the monitor's history: an alarm in progress starts over
        e.fdi.state = "monitoring" if f["state"] == "alarm" else f["state"]
        e.fdi.failed_by_fdi = set(f["failed"])
        e.fdi.flagged_only = set(f["flagged_only"])
        e.fdi.counts.update(f["counts"])
