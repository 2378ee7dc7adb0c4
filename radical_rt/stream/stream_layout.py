"""Layout of the stream processor's two small shared state arrays (read and written by the
compiled intakes :func:`radical_rt.stream.siru_wire.siru_intake` and
:func:`radical_rt.stream.tracker_queue.tracker_intake`, and by the stream in Python), declared once with
:class:`radical_rt.contract.layout.Fields`.

``ss`` (float64): the stream's times [s]; ``si`` (int64): the tracker queue's counters and row
range. ``SS_LAST + j`` is the last t_bus of tracker j = 1, 2.
"""

from __future__ import annotations

from radical_rt.contract.layout import Fields

SS = Fields("stream.ss", "float64")
SS_T_MAX = SS.add("t_max", unit="s", doc="newest t_bus of any input")
SS_RELEASED = SS.add("released", unit="s", doc="epoch up to which samples count as released")
SS_LAST_ST1 = SS.add("last_st1", unit="s", doc="last t_bus of tracker 1")
SS_LAST_ST2 = SS.add("last_st2", unit="s", doc="last t_bus of tracker 2")
SS_T_IN = SS.add("t_in", unit="s",
                 doc="t_bus of the last tracker sample taken in or refused (diagnostics)")
SS_LAST_SIRU = SS.add("last_siru", unit="s", doc="last t_bus of the previous siru batch")
SS_WINDOW = SS.add("window", unit="s",
                   doc="plausibility window W of both intakes (configuration; inf: off)")
SS.freeze()
SS_LAST = SS_LAST_ST1 - 1  # SS_LAST + j: tracker j

SI = Fields("stream.si", "int64")
SI_LATE = SI.add("late", doc="late tracker samples dropped")
SI_SEQ = SI.add("seq", doc="arrival counter")
SI_HEAD = SI.add("head", doc="first waiting row of the tracker queue")
SI_END = SI.add("end", doc="one past the last waiting row")
SI.freeze()
