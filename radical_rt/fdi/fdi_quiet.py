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
test fires and the ring of taken sums has room (the loop itself checks that the engine did not
restart and that no excitation step is due). A sum at which the monitor's snapshot is due (every
5 s) is taken while monitoring too: the loop copies the engine's state into a slot after the
array's fields, as the hook would have copied it (:func:`put_snapshot`), and the monitor makes
the snapshot record after the call. During an alarm whose bank the loop runs itself the hook of
a sum only records the detector's step and the time (the bank decides at tracker samples, and
hands over there), so the loop then takes every sum at which no snapshot is due, whatever the
tests say. Every other sum goes to the hook as before, so the decisions and records are the
same (tests/radical_rt/fdi/test_fdi_quiet.py); the monitor takes the taken sums' records and
snapshots after the call (:meth:`radical_rt.fdi.monitor.FaultMonitor.sums_taken`).
"""

from __future__ import annotations

import math

from radical_rt._jit import inline_kernel, kernel
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
Q_SNAP_LEN = QF.add("snap_len", doc="floats of a snapshot slot (snapshot_size; 0: no slots)")
Q_SNAPS = QF.add("snaps", doc="snapshots taken since the monitor last looked (out)")
QF.freeze()
QF_END = QF.end  # (a plain int: the snapshot slots start here)
SNAP_SLOTS = 4  # snapshots one compiled call may take before the hook must take the next one


@kernel
def take_sum(fq, t_c, nu, rho, t0, z, q, omega, xp, U, d, N, seq):
    """Whether the loop takes the parity sum that closed at engine time t_c [s] (statistic nu,
    rho, t0 [s], z [rad]) for the FDI (module docstring): TAKE_NONE (the hook takes it), else
    fq[Q_ON]'s mode. fq (QF.end + slots,) in place: when taken the detector's statistics moved
    and the sum is recorded. A sum at which the monitor's snapshot is due (Q_SNAP_PERIOD after
    Q_SNAP_T) is taken only while monitoring, with a valid attitude (seq ≥ 0) and a free slot:
    the engine's state then (q (4,), omega (3,), xp (npar,), U (ns, ns), d (ns,), N (n, n − 3); seq the
    last tracker sample applied) goes to the next slot (:func:`put_snapshot`)."""
    mode = int(fq[Q_ON])
    if mode == TAKE_NONE:
        return TAKE_NONE
    n = int(fq[Q_TAKEN])
    if n >= RING:
        return TAKE_NONE
    snap = not t_c - fq[Q_SNAP_T] < fq[Q_SNAP_PERIOD]
    if snap and not (mode == TAKE_QUIET and seq >= 0 and math.isfinite(t_c)
                     and fq[Q_SNAP_LEN] == snapshot_size(xp.shape[0], d.shape[0], N.size)
                     and QF_END + (fq[Q_SNAPS] + 1) * fq[Q_SNAP_LEN] <= fq.shape[0]):
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
    if snap:
        put_snapshot(fq, t_c, q, omega, xp, U, d, N, seq)
    return mode


@inline_kernel
def snapshot_size(npar, ns, n_null):
    """Floats of a snapshot slot (:func:`slot_views`): t [s], seq, q (4), omega (3), xp (npar),
    U (ns²), d (ns), N (n_null)."""
    return 9 + npar + ns * ns + ns + n_null


@inline_kernel
def slot_views(fq, k, npar, ns, n_rows, n_cols):
    """Views of snapshot slot k of fq (slots of :func:`snapshot_size` floats from QF.end on), in
    the slot's order: (t, seq) (2,), q (4,), omega (3,), xp (npar,), U (ns, ns), d (ns,),
    N (n_rows, n_cols): the one declaration of the slot's layout, for :func:`put_snapshot` and
    the monitor (radical_rt.fdi.monitor_snapshots)."""
    o = QF_END + k * snapshot_size(npar, ns, n_rows * n_cols)
    head, q, omega = fq[o:o + 2], fq[o + 2:o + 6], fq[o + 6:o + 9]
    o += 9
    xp = fq[o:o + npar]
    o += npar
    U = fq[o:o + ns * ns].reshape((ns, ns))
    o += ns * ns
    d = fq[o:o + ns]
    o += ns
    return head, q, omega, xp, U, d, fq[o:o + n_rows * n_cols].reshape((n_rows, n_cols))


@inline_kernel
def put_snapshot(fq, t, q, omega, xp, U, d, N, seq):
    """The engine's state at engine time t [s] (arguments as in :func:`take_sum`) into fq's next
    snapshot slot (Q_SNAPS of them are in use); the newest snapshot's time Q_SNAP_T becomes t.
    The monitor makes its Snapshot records from them
    (radical_rt.fdi.monitor.FaultMonitor.sums_taken)."""
    k = int(fq[Q_SNAPS])
    head, q_s, omega_s, xp_s, U_s, d_s, N_s = slot_views(fq, k, xp.shape[0], d.shape[0],
                                                         N.shape[0], N.shape[1])
    head[0], head[1] = t, seq
    q_s[:] = q
    omega_s[:] = omega
    xp_s[:] = xp
    U_s[:, :] = U
    d_s[:] = d
    N_s[:, :] = N
    fq[Q_SNAPS] = k + 1
    fq[Q_SNAP_T] = t
