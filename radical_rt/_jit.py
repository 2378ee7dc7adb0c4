"""The single Numba policy of RADICAL-RT.

Every compiled kernel is declared with :func:`kernel`: ``cache=True`` (compiled once, loaded from
``__pycache__`` afterwards), ``fastmath=False`` (bit-reproducible), ``nogil=False``,
``error_model='numpy'`` (no Python exceptions for division by zero inside kernels; kernels return
status codes instead). The one other form is :mod:`radical_rt.kernels.flat_views`: functions with
a NumPy body for Python and a compiled body (``numba.extending.overload`` with
:data:`JIT_POLICY`) inlined into the kernels that call them.

``nogil=False``: the kernels run for microseconds, and releasing the GIL around each of them
(about 20 calls per input message) handed it to any other Python thread that wanted it, and the
filter loop then waited to get it back. With Zenoh callback threads in the node this ping-pong
was measured to cost about a sixth of the node's capacity (perf/README.md).

**Stale caches.** Numba keys a cached kernel on its own source file only. A kernel that calls
kernels of other modules (``loop.run_release`` calls into ``propagate``, ``timeupdate``,
``updates``, ``ud``, ``model``…) embeds their machine code, and after an edit of one of those
modules it went on running the *old* callee from its cache while direct callers ran the new one.
:func:`_drop_stale_cache` therefore treats the cached kernels of a source directory as one unit:
a fingerprint of the Numba version, ``_POLICY`` and the contents of every kernel module (a
``.py`` file that declares kernels) of the whole ``radical_rt/`` tree (subpackages included) and
of the kernel's own directory tree, and of every module of those trees they import (directly or
not: a layout module's constants are frozen into the compiled code too), is kept in
``__pycache__/kernels.stamp`` of each directory;
when it changes, every cached kernel there (``*.nbi``, ``*.nbc``) is deleted before the first
kernel of that directory is declared, so everything is compiled afresh. (This covers Numba's
default cache location next to the sources; with ``NUMBA_CACHE_DIR`` set, clear that directory
after editing kernels.)
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import numba
from numba import njit

_POLICY = dict(cache=True, fastmath=False, nogil=False, error_model="numpy")
#: the policy as ``jit_options`` of a ``numba.extending.overload`` (compiled into its callers,
#: which are cached)
JIT_POLICY = {k: v for k, v in _POLICY.items() if k != "cache"}
_PACKAGE = Path(__file__).resolve().parent
_INSTALLED = _PACKAGE  # (_PACKAGE itself is replaced by the cache tests)
_checked: set[Path] = set()


_IMPORT = re.compile(rb"^\s*(?:from|import)\s+([^\n]*)", re.MULTILINE)


def _kernel_sources(d: Path) -> list[Path]:
    """The kernel modules of the tree under d (subpackages included) and the modules of that
    tree they import, transitively. An imported name is matched against module file names
    anywhere in the tree (``from .layout import X`` and ``from ..kernels import layout`` both
    reach every ``layout.py``): over-inclusive, so a change is never missed."""
    files = sorted(p for p in d.rglob("*.py") if "__pycache__" not in p.parts)
    texts = {p: p.read_bytes() for p in files}
    by_stem: dict[str, list[Path]] = {}
    for p in files:
        by_stem.setdefault(p.stem, []).append(p)
    todo = [p for p, t in texts.items()
            if b"@kernel" in t or b"@inline_kernel" in t or b"njit(" in t or b"@overload(" in t]
    keep: set[Path] = set()
    while todo:
        path = todo.pop()
        if path in keep:
            continue
        keep.add(path)
        for line in _IMPORT.findall(texts[path]):
            for w in re.findall(rb"\w+", line):
                todo += by_stem.get(w.decode(), [])
    return sorted(keep)


def _fingerprint(directory: Path) -> str:
    """Hash of the Numba version, the policy, and the kernel modules of the package's whole tree
    and of ``directory``'s tree (when outside the package) with the modules they import."""
    h = hashlib.sha256(f"{numba.__version__}|{sorted(_POLICY.items())}".encode())
    roots = {_PACKAGE} if directory.is_relative_to(_PACKAGE) else {_PACKAGE, directory}
    for d in sorted(roots):
        for rel, text in (_package_tree() if d == _INSTALLED else _tree(d)):
            h.update(rel)
            h.update(text)
    return h.hexdigest()


def _tree(d: Path) -> list[tuple[bytes, bytes]]:
    """(path relative to d, contents) of the kernel modules of :func:`_kernel_sources`."""
    return [(str(src.relative_to(d)).encode(), src.read_bytes()) for src in _kernel_sources(d)]


def _package_tree(memo: list = []) -> list[tuple[bytes, bytes]]:  # noqa: B006 (the memo)
    """:func:`_tree` of the installed package, read once per process: each directory of kernels
    is checked at its first kernel, all at start-up (reading and scanning the tree took ≈ 10 ms a
    time). (Not for another ``_PACKAGE``, which the cache tests build and edit.)"""
    if not memo:
        memo.append(_tree(_INSTALLED))
    return memo[0]


def _drop_stale_cache(source_file: str) -> None:
    """Delete the cached kernels next to ``source_file`` if any source they may embed changed
    (see the module docstring). Never raises: without a writable cache it does nothing."""
    directory = Path(source_file).resolve().parent
    if directory in _checked:
        return
    _checked.add(directory)
    cache = directory / "__pycache__"
    stamp = cache / "kernels.stamp"
    try:
        fp = _fingerprint(directory)
        if stamp.is_file() and stamp.read_text() == fp:
            return
        if cache.is_dir():
            for f in [*cache.glob("*.nbi"), *cache.glob("*.nbc")]:
                f.unlink(missing_ok=True)
        cache.mkdir(exist_ok=True)
        stamp.write_text(fp)
    except OSError:
        pass


def kernel(fn):
    """Compile ``fn`` with the project's Numba policy."""
    _drop_stale_cache(fn.__code__.co_filename)
    return njit(**_POLICY)(fn)


# Status codes returned by kernels (never raised).
OK = 0
ERR_NOT_POSITIVE = 1  # a variance or pivot became non-positive or non-finite
ERR_SHAPE = 2  # inconsistent array sizes
ERR_NONFINITE = 3  # a NaN or Inf in an input


def inline_kernel(fn):
    """:func:`kernel` inlined into its callers at Numba IR level (``inline='always'``): for the
    helpers of :mod:`radical_rt.engine.loop` that take the tuple of engine arrays, whose reference
    counting per call would otherwise cost more than their arithmetic."""
    _drop_stale_cache(fn.__code__.co_filename)
    return njit(inline="always", **_POLICY)(fn)
