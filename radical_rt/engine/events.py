"""Steps of the engine that Python asks for outside a release (:func:`engine_event`), and the
start of every compiled call (:func:`begin_call`).

Commands (cold and warm starts, an isolation), Python's own numeric checks and the end of a
stream run the engine's compiled steps (:mod:`radical_rt.engine.steps`) on the packed state
through this one kernel, on the scalar state the engine keeps in its io and cnt arrays
(``LoopShell._event``), so no step has a second implementation in Python.
"""

from __future__ import annotations

import math

from radical_rt._jit import inline_kernel, kernel
from radical_rt.engine.engine_layout import E_INDEX, unpack
from radical_rt.engine.loop_layout import (
    CNT_FLAGS,
    CNT_FLAGS0,
    IO_MODE,
    IO_SIG_T,
    IO_WAKE_E,
    IO_WAKE_FDI,
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
def begin_call(io, cnt, sig_t, wake_t, wake_e, wake_fdi):
    """The start of a compiled call: the collaborators' inputs into io (σ of the time line [s];
    wake_t, wake_e, wake_fdi [s]: see radical_rt.engine.loop) and the flags at the start of the
    call (CNT_FLAGS0). The rest of the engine's scalar state is kept in io and cnt between calls
    (``LoopShell``: the engine's attributes are views of it); the counters accumulate until
    Python takes them (``LoopShell._drain``)."""
    io[IO_SIG_T], io[IO_WAKE_T], io[IO_WAKE_E] = sig_t, wake_t, wake_e
    io[IO_WAKE_FDI] = wake_fdi
    cnt[CNT_FLAGS0] = cnt[CNT_FLAGS]


# engine_event codes
EV_BEGIN_ATTITUDE_INIT, EV_NUMERIC, EV_FLUSH, EV_RESET_PARITY, EV_WINDOW_STATE = 0, 1, 2, 3, 4


@kernel
def engine_event(code, arg, t_arg, fb, ib, bb, lay, cfg, io, cnt, sig_t):
    """One of the engine's steps run for Python (commands, checks, the end of a stream) on the
    packed state and the scalar state in io and cnt (sig_t: σ of the time line [s], as for
    :func:`run_release`):
    EV_BEGIN_ATTITUDE_INIT (the attitude is lost; steps.begin_attitude_init), EV_NUMERIC (a
    numeric fault with code ``arg``; steps.numeric_fault), EV_FLUSH (the end of a stream: the
    open parity sum queued, every queued sum updated, the correction folded), EV_RESET_PARITY
    (the open parity sum dropped), EV_WINDOW_STATE (the flags and the mode after a close at
    event time ``t_arg``, steps.window_state)."""
    begin_call(io, cnt, sig_t, math.inf, math.inf, math.inf)
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
