"""Records of the FDI monitor's snapshots, for tests: every Snapshot the monitor makes (by its
window hook or from the slots the engine's compiled loop filled, radical_rt.fdi.monitor_snapshots)
as a comparable tuple (t, trk_seq, gen, then each array's bytes and shape)."""

from __future__ import annotations

from radical_rt.fdi import monitor_snapshots
from radical_rt.fdi.fdi_history import Snapshot

_ARRAYS = ("q", "omega", "xp", "U", "d", "N")


def record_snapshots(monkeypatch) -> list[tuple]:
    """Patch the monitor's Snapshot (with ``monkeypatch``, a pytest MonkeyPatch) so that every
    snapshot it makes is appended to the returned list."""
    made: list[tuple] = []

    class Recorded(Snapshot):
        def __init__(self, **fields):
            super().__init__(**fields)
            made.append((self.t, self.trk_seq, self.gen) + tuple(
                getattr(self, k).tobytes() + str(getattr(self, k).shape).encode()
                for k in _ARRAYS))

    monkeypatch.setattr(monitor_snapshots, "Snapshot", Recorded)
    return made
