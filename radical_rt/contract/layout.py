"""Flat-array layouts declared once.

Compiled kernels keep structured state in a few flat numpy arrays (one call argument each instead
of one per field) and read it by integer offsets. :class:`Fields` declares such an array field by
field, in order: each :meth:`Fields.add` returns the field's offset, which follows from the sizes
declared before it, so no offset is written by hand. The module-level names a layout module binds
to those offsets are plain ints, which Numba freezes as compile-time constants::

    CFG = Fields("engine.cfg", "float64")
    CFG_PROP_WINDOW = CFG.add("prop_window", doc="samples per time-update window")
    CFG_ARW_VAR = CFG.add("arw_var", unit="rad^2/s")
    CFG.freeze()

    cfg = CFG.pack({"prop_window": 10, "arw_var": 1e-12})   # every field, sizes checked
    CFG.unpack(cfg)["arw_var"]                               # a view

The same declaration gives the checks (:meth:`Fields.check` for a restored checkpoint's array),
names for diagnostics (:meth:`Fields.name_at`) and the documentation table
(:meth:`Fields.table`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Field:
    """One field: ``name`` at ``offset`` .. ``offset + size − 1``; unit and meaning for docs."""

    name: str
    offset: int
    size: int
    unit: str = ""
    doc: str = ""

    @property
    def slice(self) -> slice:
        return slice(self.offset, self.offset + self.size)


class Fields:
    """The layout of one flat array (see the module docstring). ``start``: offset of the first
    field (a layout may continue another one in the same array, :meth:`follow`)."""

    def __init__(self, name: str, dtype: str = "float64", start: int = 0) -> None:
        self.name = name
        self.dtype = np.dtype(dtype)
        self.start = start
        self._fields: dict[str, Field] = {}
        self._end = start
        self._frozen = False

    def add(self, name: str, size: int = 1, unit: str = "", doc: str = "") -> int:
        """Declare the next field; returns its offset."""
        if self._frozen:
            raise RuntimeError(f"layout {self.name} is frozen; cannot add {name!r}")
        if name in self._fields:
            raise ValueError(f"layout {self.name}: field {name!r} declared twice")
        if size < 0:
            raise ValueError(f"layout {self.name}: field {name!r} has size {size}")
        f = Field(name, self._end, int(size), unit, doc)
        self._fields[name] = f
        self._end += f.size
        return f.offset

    def freeze(self) -> Fields:
        """No more fields (a layout is complete once its module is imported)."""
        self._frozen = True
        return self

    def follow(self, name: str, dtype: str | None = None) -> Fields:
        """A new layout starting where this one ends (the next part of the same array)."""
        return Fields(name, str(self.dtype) if dtype is None else dtype, self._end)

    # ------------------------------------------------------------------ queries
    @property
    def size(self) -> int:
        """Elements from ``start`` to the end of the last field."""
        return self._end - self.start

    @property
    def end(self) -> int:
        """Offset just past the last field."""
        return self._end

    @property
    def fields(self) -> tuple[Field, ...]:
        return tuple(self._fields.values())

    def __getitem__(self, name: str) -> Field:
        try:
            return self._fields[name]
        except KeyError:
            raise KeyError(f"layout {self.name} has no field {name!r}; fields: "
                           + ", ".join(self._fields)) from None

    def __contains__(self, name: str) -> bool:
        return name in self._fields

    def name_at(self, offset: int) -> str:
        """The field holding ``offset`` (``name[i]`` inside a multi-element field)."""
        for f in self._fields.values():
            if f.offset <= offset < f.offset + f.size:
                return f.name if f.size == 1 else f"{f.name}[{offset - f.offset}]"
        raise IndexError(f"offset {offset} is outside layout {self.name} "
                         f"[{self.start}, {self._end})")

    # ------------------------------------------------------------------ packing and checks
    def pack(self, values: Mapping[str, Any], out: np.ndarray | None = None) -> np.ndarray:
        """An array (or ``out``, written from ``start``) holding every field of ``values``;
        every field must be given, with its size (scalars for size-1 fields)."""
        missing = [n for n in self._fields if n not in values]
        extra = [n for n in values if n not in self._fields]
        if missing or extra:
            raise ValueError(f"layout {self.name}: missing {missing}, unknown {extra}")
        a = np.zeros(self._end, self.dtype) if out is None else out
        for f in self._fields.values():
            v = np.asarray(values[f.name], dtype=self.dtype).reshape(-1)
            if v.size != f.size:
                raise ValueError(f"layout {self.name}: field {f.name!r} needs {f.size} "
                                 f"value(s), got {v.size}")
            a[f.slice] = v
        return a

    def unpack(self, a: np.ndarray) -> dict[str, Any]:
        """Field name → value (a Python scalar for size-1 fields, else a view)."""
        return {f.name: (a[f.offset].item() if f.size == 1 else a[f.slice])
                for f in self._fields.values()}

    def check(self, a: Any, what: str = "") -> list[str]:
        """Problems of ``a`` as an array of this layout (empty when it fits): type, dtype,
        length at least :attr:`end`."""
        label = what or self.name
        if not isinstance(a, np.ndarray):
            return [f"{label}: expected an array, got {type(a).__name__}"]
        probs = []
        if a.dtype != self.dtype:
            probs.append(f"{label}: dtype {a.dtype}, expected {self.dtype}")
        if a.ndim != 1 or a.shape[0] < self._end:
            probs.append(f"{label}: shape {a.shape}, expected at least ({self._end},)")
        return probs

    def table(self) -> str:
        """The layout as a Markdown table (offset, field, size, unit, meaning)."""
        rows = ["| offset | field | size | unit | meaning |", "|---|---|---|---|---|"]
        rows += [f"| {f.offset} | `{f.name}` | {f.size} | {f.unit} | {f.doc} |"
                 for f in self._fields.values()]
        return "\n".join(rows)
