"""The stream's rules that the block intake (:mod:`radical_rt.stream.intake_block`) applies in
compiled code, each the compiled form of one Python rule: the stream's flags and the wake times
of its hooks (:func:`stream_flags`, :func:`stream_wake`; Python's
:class:`radical_rt.stream.outputs.StreamOutputs`), the sample-triggered packets' schedule
(:func:`packet_due`, :meth:`radical_rt.stream.telemetry.PacketSpec.due`) and their rows
(:func:`sample_rows`, :func:`siru_done`; Python makes the messages from them,
:meth:`radical_rt.stream.block_feed.BlockFeed._rows_done`). Scalars in the block's control
arrays bi, bf (BI_*, BF_* of :mod:`radical_rt.stream.stream_layout`).
"""

from __future__ import annotations

import math

from radical_rt._jit import kernel
from radical_rt.clock.clock_layout import F_ANOM_UNTIL, F_TAU_NOW
from radical_rt.contract.flags import Flag
from radical_rt.engine.engine_layout import E_INDEX, propagation_work, unpack
from radical_rt.engine.gyro_queue import predict_pending
from radical_rt.engine.loop_layout import CNT_FLAGS, IO_ATT_VALID, IO_MODE, IO_T
from radical_rt.stream.stream_layout import (
    BF_LAST_REJECT,
    BF_REJECT_HOLD,
    BF_T_NOW,
    BF_WAKE_E,
    BF_WAKE_T,
    BI_GQ_END,
    BI_GQ_HEAD,
    BI_GUARD_FLAGS,
    BI_LAST_FLAGS,
    BI_NEW_SAMPLE,
    BI_ROWS,
    BI_ROWS_OK,
    BI_SIRU_LEFT,
    SS_T_MAX,
)

_CLOCK_ANOMALY, _INPUT_REJECTED = int(Flag.CLOCK_ANOMALY), int(Flag.INPUT_REJECTED)
# positions in the engine's tuple of views (radical_rt.engine.engine_layout)
_Q, _OMEGA, _EXCLUDED = E_INDEX["q"], E_INDEX["omega"], E_INDEX["excluded"]
_XP, _A, _GP = E_INDEX["xp"], E_INDEX["A"], E_INDEX["Gp"]


@kernel
def stream_flags(bi, bf, ss, io, cnt, clock_F):
    """The stream's flags (:attr:`radical_rt.stream.outputs.StreamOutputs.flags`): the engine's,
    CLOCK_ANOMALY from the clock's state, the INPUT_REJECTED hold, the guards' BI_GUARD_FLAGS
    (constant while no guard is live, which the caller makes sure of)."""
    flags = cnt[CNT_FLAGS]
    if clock_F[F_TAU_NOW] < clock_F[F_ANOM_UNTIL]:
        flags |= _CLOCK_ANOMALY
    last_reject = bf[BF_LAST_REJECT]
    if io[IO_T] - last_reject <= bf[BF_REJECT_HOLD] or ss[SS_T_MAX] == last_reject:
        flags |= _INPUT_REJECTED
    return flags | bi[BI_GUARD_FLAGS]


@kernel
def stream_wake(bi, bf, ss, io, cnt, clock_F):
    """The wake times (event time, engine time [s]) of the stream's hooks for a compiled call:
    :meth:`radical_rt.stream.outputs.StreamOutputs.wake`, as
    :meth:`radical_rt.engine.shell.LoopShell._call_inputs` gives them (the FDI's wake time,
    BF_WAKE_FDI, goes to the call separately): −inf for both when the stream's flags
    (:func:`stream_flags`) differ from the last fault message's."""
    last = bi[BI_LAST_FLAGS]
    if stream_flags(bi, bf, ss, io, cnt, clock_F) != last:
        return -math.inf, -math.inf
    last_reject = bf[BF_LAST_REJECT]
    wake_e = bf[BF_WAKE_E]
    if last & _INPUT_REJECTED and ss[SS_T_MAX] != last_reject:
        wake_e = min(wake_e, last_reject + bf[BF_REJECT_HOLD] - 1e-6)
    return bf[BF_WAKE_T], wake_e


@kernel
def packet_due(sp_f, sp_i, s, t):
    """PacketSpec.due of sample-triggered packet s at sample time t [s]: sp_f (S, 2) next time
    [s], period [s] (0: none); sp_i (S, 2) decimation (0: none), windows counted (in/out)."""
    dec = sp_i[s, 0]
    if dec > 0:
        sp_i[s, 1] += 1
        if sp_i[s, 1] >= dec:
            sp_i[s, 1] = 0
            return True
        return False
    if t >= sp_f[s, 0]:
        sp_f[s, 0] = t + 0.95 * sp_f[s, 1]
        return True
    return False


@kernel
def sample_rows(bi, bf, ss, io, cnt, cI, cF, pred, sp_f, sp_i, rows_f, rows_i, q_dth, q_dt,
                 q_st, fb, ib, bb, lay):
    """The sample-triggered packets due at the newest sample (StreamOutputs._sample_outputs): a
    row each (BI_ROWS of them so far) of rows_f (R, 8): t [s], q_body_from_inertial (4,),
    omega_body (3,) [rad/s] predicted to the newest sample (the release's prediction, else
    StreamOutputs.now's); rows_i (R, 3): the packet's index, the stream's flags, the mode code."""
    t_now = bf[BF_T_NOW]
    first = -1
    for s in range(sp_f.shape[0]):
        if not packet_due(sp_f, sp_i, s, t_now):
            continue
        r = bi[BI_ROWS]
        bi[BI_ROWS] = r + 1
        rows_i[r, 0] = s
        if first >= 0:  # (one prediction for the packets of one sample)
            rows_i[r, 1], rows_i[r, 2] = rows_i[first, 1], rows_i[first, 2]
            for c in range(8):
                rows_f[r, c] = rows_f[first, c]
            continue
        first = r
        rows_i[r, 1] = stream_flags(bi, bf, ss, io, cnt, cF)
        rows_i[r, 2] = int(io[IO_MODE])
        row = rows_f[r]
        if pred[0] == 2.0:
            for c in range(8):
                row[c] = pred[1 + c]
            continue
        E = unpack(fb, ib, bb, lay)
        q, omega = row[1:5], row[5:8]
        for c in range(4):
            q[c] = E[_Q][c]
        for c in range(3):
            omega[c] = E[_OMEGA][c]
        row[0] = io[IO_T]
        if io[IO_ATT_VALID] != 0.0:
            row[0] = predict_pending(q_dth, q_dt, q_st, bi[BI_GQ_HEAD], bi[BI_GQ_END], t_now, cI,
                                     cF, E[_EXCLUDED], E[_XP], E[_A], E[_GP], q, omega,
                                     propagation_work(E))


@kernel
def siru_done(bi, bf, ss, io, cnt, cI, cF, pred, sp_f, sp_i, rows_f, rows_i, q_dth, q_dt, q_st,
               fb, ib, bb, lay):
    """After a siru message's release: its sample-triggered packets as rows (:func:`sample_rows`)
    when the rows are on (BI_ROWS_OK). Returns True when the block call must stop after this
    message (its packets are Python's, or the call has taken as many siru messages as the
    caller made room for), False to go on."""
    if bi[BI_ROWS_OK] == 0:
        return True  # its sample-triggered packets are Python's
    if bi[BI_NEW_SAMPLE] != 0:
        sample_rows(bi, bf, ss, io, cnt, cI, cF, pred, sp_f, sp_i, rows_f, rows_i, q_dth, q_dt,
                     q_st, fb, ib, bb, lay)
    bi[BI_SIRU_LEFT] -= 1
    return bi[BI_SIRU_LEFT] == 0  # (the room made is for so many)
