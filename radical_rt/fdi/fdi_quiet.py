"""Parity sums the engine's compiled loop takes for the FDI without stopping for its window hook.

Outside an alarm, the FDI's work at the window close of a parity sum is the detector's step on
the sum's statistic (ν, ρ, t0, z), a few records, and bookkeeping that changes nothing unless
the engine restarted, a snapshot is due or the configuration changed
(:meth:`radical_rt.fdi.monitor.FaultMonitor.on_window`). Stopping the compiled loop for that,
once a second, cost about a tenth of a run. So the monitor hands the loop this module's array
(layout :data:`QF`: whether it may, the snapshot time and period, the detector's statistics and
configuration of :mod:`radical_rt.fdi.fdi_detect`), and at a close where nothing else needs the
hook the loop calls :func:`take_sum`: the detector's own step
(:func:`radical_rt.fdi.fdi_detect.detector_step`) on a copy of the statistics, kept only when no
test fires, no snapshot is due and the ring of taken sums has room (the loop itself checks that
the engine did not restart and that no excitation step is due). During an alarm whose bank the
loop runs itself the hook of a sum only records the detector's step and the time (the bank
decides at tracker samples, and hands over there), so the loop then takes every sum at which no
snapshot is due, whatever the tests say. Every other sum goes to the hook as before, so the
decisions and records are the same (tests/radical_rt/fdi/test_fdi_quiet.py); the monitor takes
the taken sums' records after the call (:meth:`radical_rt.fdi.monitor.FaultMonitor.sums_taken`).
"""

from __future__ import annotations

from radical_rt._jit import kernel
from radical_rt.contract.layout import Fields
from radical_rt.fdi.fdi_detect import DET, DTH, HIT_NONE, detector_step

RING = 32  # sums one compiled call may take before the hook must take the next one
#: Q_ON values and take_sum's results: while monitoring a sum at which a test fires goes to the
#: hook (it raises the alarm); during an alarm whose bank the loop runs the hook would only
#: record the step (a running bank ignores the tests), so the loop keeps every step
TAKE_NONE, TAKE_QUIET, TAKE_ALARM = 0, 1, 2
_N_DET, _N_TH = DET.end, DTH.end  # (plain ints: compile-time constants)

QF = Fields("fdi.quiet", "float64")
Q_ON = QF.add("on", doc="the loop may take sums (set by the monitor before each call): 0 no, "
                        "TAKE_QUIET while monitoring, TAKE_ALARM during an alarm whose bank "
                        "the loop runs")
Q_SNAP_T = QF.add("snap_t", unit="s", doc="engine time of the newest snapshot (-inf: none)")
Q_SNAP_PERIOD = QF.add("snap_period", unit="s", doc="a snapshot is due this long after the last")
Q_CHECK_S = QF.add("check_s", unit="s", doc="the bookkeeping is due this long after a sum")
Q_TAKEN = QF.add("taken", doc="sums taken since the monitor last looked (out)")
Q_LAST = QF.add("last", 3, unit="-, -, s", doc="the last taken sum's nu, rho, close time (out)")
Q_DET = QF.add("det", DET.end, doc="the detector's statistics (fdi_detect.DET; in/out)")
Q_TH = QF.add("th", DTH.end, doc="the detector's configuration (fdi_detect.DTH)")
Q_WORK = QF.add("work", DET.end, doc="scratch: the statistics of a tentative step")
Q_RING = QF.add("ring", 2 * RING, unit="s, rad", doc="the taken sums' (t0, z), in order (out)")
QF.freeze()


@kernel
def take_sum(fq, t_c, nu, rho, t0, z):
    """Whether the loop takes the parity sum that closed at engine time t_c [s] (statistic nu,
    rho, t0 [s], z [rad]) for the FDI (module docstring): TAKE_NONE (the hook takes it), else
    fq[Q_ON]'s mode. fq (QF.end,) in place: when taken the detector's statistics moved and the
    sum is recorded."""
    mode = int(fq[Q_ON])
    if mode == TAKE_NONE:
        return TAKE_NONE
    n = int(fq[Q_TAKEN])
    if n >= RING or not t_c - fq[Q_SNAP_T] < fq[Q_SNAP_PERIOD]:
        return TAKE_NONE
    s = fq[Q_WORK:Q_WORK + _N_DET]
    for i in range(_N_DET):
        s[i] = fq[Q_DET + i]
    hit, _onset = detector_step(s, fq[Q_TH:Q_TH + _N_TH], nu, rho, t0)
    if hit != HIT_NONE and mode == TAKE_QUIET:
        return TAKE_NONE  # the hook raises the alarm (its step gives the same verdict)
    for i in range(_N_DET):
        fq[Q_DET + i] = s[i]
    fq[Q_RING + 2 * n], fq[Q_RING + 2 * n + 1] = t0, z
    fq[Q_LAST], fq[Q_LAST + 1], fq[Q_LAST + 2] = nu, rho, t_c
    fq[Q_TAKEN] = n + 1
    return mode
