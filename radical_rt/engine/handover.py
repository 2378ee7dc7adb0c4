"""When the engine's compiled loop stops for the window hook (radical_rt.engine.loop): the rule
tested after every window close, and the parity sums the FDI takes in the loop instead of at the
hook (:mod:`radical_rt.fdi.fdi_quiet`).

``E``, ``cfg``, ``io``, ``cnt``: the engine's arrays and scalar state as in
:mod:`radical_rt.engine.loop` (layouts :mod:`radical_rt.engine.loop_layout`); ``fq``: the FDI's
array (zeros without FDI: it never takes a sum).
"""

from __future__ import annotations

from radical_rt._jit import inline_kernel
from radical_rt.engine.engine_layout import E_INDEX
from radical_rt.engine.loop_layout import (
    CFG_HOOK_SUM,
    CNT_ATT_INITS,
    CNT_FLAGS0,
    CNT_GAPS,
    CNT_PAR_STAT,
    CNT_PAR_SUMS,
    CNT_TRK_ADDED,
    IO_ATT_VALID,
    IO_EX_NEXT,
    IO_GEN0,
    IO_MODE,
    IO_PAR_NU,
    IO_PAR_RHO,
    IO_PAR_T0,
    IO_PAR_Z,
    IO_T,
    IO_TRK_SEQ0,
    IO_WAKE_E,
    IO_WAKE_FDI,
    IO_WAKE_T,
)
from radical_rt.engine.steps import window_state
from radical_rt.fdi.fdi_quiet import Q_CHECK_S, TAKE_NONE, TAKE_QUIET, take_sum

_Q, _OMEGA, _XP = E_INDEX["q"], E_INDEX["omega"], E_INDEX["xp"]
_U, _D, _N = E_INDEX["U"], E_INDEX["d"], E_INDEX["N"]


@inline_kernel
def window_due(E, cfg, io, cnt, fq, t_event, booked):
    """Whether the window hook (Engine.on_window(t_event)) has work after a close: the flags
    differ from those at the start of the call or would change (:func:`steps.window_state`:
    stale trackers, convergence), the mode would change, the event time reached wake_t or the
    engine time wake_e or wake_fdi (radical_rt.engine.loop), or a parity sum was queued (with
    cfg[CFG_HOOK_SUM]) that the FDI does not take here (:func:`take_sum_here`; booked: 1 after
    a tracker update, whose sample the FDI's history gets before the hook would run, else 0)."""
    f, mode = window_state(E, cfg, io, cnt, t_event)
    if (f != cnt[CNT_FLAGS0] or mode != io[IO_MODE] or t_event >= io[IO_WAKE_T]
            or io[IO_T] >= io[IO_WAKE_E] or io[IO_T] >= io[IO_WAKE_FDI]):
        return True
    if cfg[CFG_HOOK_SUM] == 0.0 or cnt[CNT_PAR_SUMS] == 0:
        return False
    return not take_sum_here(E, io, cnt, fq, booked)


@inline_kernel
def take_sum_here(E, io, cnt, fq, booked):
    """Whether the FDI takes the parity sum this close queued without the window hook
    (:func:`radical_rt.fdi.fdi_quiet.take_sum` with its array fq; the hook then had nothing
    else to do): the engine's side is that it is the only sum queued, its statistic valid, the
    engine not restarted since the FDI looked (gaps and attitude inits: IO_GEN0) and no
    excitation step due. The sum is then no longer pending, and while monitoring the FDI's
    bookkeeping is due CHECK_S after it (IO_WAKE_FDI), as its hook would have set. For the
    FDI's snapshot: the engine's state and the sequence number of the last tracker sample in
    the FDI's history at the hook (IO_TRK_SEQ0 + the samples booked since, + booked; −1
    without an attitude)."""
    if (cnt[CNT_PAR_SUMS] != 1 or cnt[CNT_PAR_STAT] != 1
            or cnt[CNT_GAPS] + cnt[CNT_ATT_INITS] != io[IO_GEN0] or not io[IO_T] < io[IO_EX_NEXT]):
        return False
    seq = io[IO_TRK_SEQ0] + cnt[CNT_TRK_ADDED] + booked if io[IO_ATT_VALID] != 0.0 else -1.0
    took = take_sum(fq, io[IO_T], io[IO_PAR_NU], io[IO_PAR_RHO], io[IO_PAR_T0], io[IO_PAR_Z],
                    E[_Q], E[_OMEGA], E[_XP], E[_U], E[_D], E[_N], seq)
    if took == TAKE_NONE:
        return False
    cnt[CNT_PAR_SUMS] = 0
    cnt[CNT_PAR_STAT] = 0
    if took == TAKE_QUIET:  # (during an alarm the FDI's wake is the bank's)
        io[IO_WAKE_FDI] = io[IO_T] + fq[Q_CHECK_S]
    return True
