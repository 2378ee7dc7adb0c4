"""Steps of the engine that Python asks for outside a release (:func:`engine_event`), and the
loading of the engine's scalar state that every compiled call starts with (:func:`load_scalars`).

Commands (cold and warm starts, an isolation), Python's own numeric checks and the end of a
stream run the engine's compiled steps (:mod:`radical_rt.engine.steps`) on the packed state
through this one kernel, with the scalar state loaded and handed back as for a release
(``LoopShell._event``), so no step has a second implementation in Python.
"""

from __future__ import annotations

import math

from radical_rt._jit import inline_kernel, kernel
from radical_rt.engine.engine_layout import E_INDEX, unpack
from radical_rt.engine.loop_layout import (
    CNT_END,
    CNT_FLAGS,
    CNT_FLAGS0,
    CNT_MASKED,
    CNT_USED,
    IO_ATT_VALID,
    IO_LAST_ST1,
    IO_LAST_ST2,
    IO_LOCKED_SINCE,
    IO_MODE,
    IO_NIS_SUM_PAR,
    IO_SIG_T,
    IO_T,
    IO_WAKE_E,
    IO_WAKE_T,
)
from radical_rt.engine.steps import (
    begin_attitude_init,
    fold,
    numeric_fault,
    pop_parity,
    queue_parity,
    reset_parity,
    window_state,
)

_PQ_I = E_INDEX["pq_i"]


@inline_kernel
def load_scalars(io, cnt, s_t, s_locked, s_sig_t, wake_t, wake_e, s_att, s_last1, s_last2,
                 s_mode, s_flags, s_nis_par):
    """The engine's scalar state into io and cnt at the start of a call (LoopShell._loop_begin;
    Python reads it back after the call): engine time [s], lock latch [s], σ of the time line
    [s], wake_t and wake_e [s], attitude valid (0/1), last valid ST1 and ST2 epochs [s], mode
    code, flags, and the sum of the parity NIS. The per-call counters of cnt (CNT_USED on) ← 0,
    CNT_MASKED ← −1."""
    io[IO_T], io[IO_LOCKED_SINCE], io[IO_SIG_T] = s_t, s_locked, s_sig_t
    io[IO_WAKE_T], io[IO_WAKE_E], io[IO_ATT_VALID] = wake_t, wake_e, s_att
    io[IO_LAST_ST1], io[IO_LAST_ST2], io[IO_MODE] = s_last1, s_last2, s_mode
    io[IO_NIS_SUM_PAR] = s_nis_par
    cnt[CNT_FLAGS], cnt[CNT_FLAGS0] = s_flags, s_flags
    for i in range(CNT_USED, CNT_END):
        cnt[i] = 0
    cnt[CNT_MASKED] = -1

# engine_event codes
EV_BEGIN_ATTITUDE_INIT, EV_NUMERIC, EV_FLUSH, EV_RESET_PARITY, EV_WINDOW_STATE = 0, 1, 2, 3, 4


@kernel
def engine_event(code, arg, t_arg, fb, ib, bb, lay, cfg, io, cnt, s_t, s_locked, s_sig_t, s_att,
                 s_last1, s_last2, s_mode, s_flags, s_nis_par):
    """One of the engine's steps run for Python (commands, checks, the end of a stream) on the
    packed state, with the scalar state loaded as for :func:`run_release`:
    EV_BEGIN_ATTITUDE_INIT (the attitude is lost; steps.begin_attitude_init), EV_NUMERIC (a
    numeric fault with code ``arg``; steps.numeric_fault), EV_FLUSH (the end of a stream: the
    open parity sum queued, every queued sum updated, the correction folded), EV_RESET_PARITY
    (the open parity sum dropped), EV_WINDOW_STATE (the flags and the mode after a close at
    event time ``t_arg``, steps.window_state)."""
    load_scalars(io, cnt, s_t, s_locked, s_sig_t, math.inf, math.inf, s_att, s_last1, s_last2,
                 s_mode, s_flags, s_nis_par)
    E = unpack(fb, ib, bb, lay)
    if code == EV_BEGIN_ATTITUDE_INIT:
        begin_attitude_init(E, io, cnt)
    elif code == EV_NUMERIC:
        numeric_fault(E, io, cnt, arg)
    elif code == EV_FLUSH:
        queue_parity(E, cfg, io, cnt)
        while E[_PQ_I][1] > 0:
            pop_parity(E, cfg, io, cnt)
        fold(E, io, cnt)
    elif code == EV_RESET_PARITY:
        reset_parity(E)
    elif code == EV_WINDOW_STATE:
        f, mode = window_state(E, cfg, io, cnt, t_arg)
        cnt[CNT_FLAGS] = f
        io[IO_MODE] = mode
