"""The single Numba policy of RADICAL-RT.

Every compiled kernel is declared with :func:`kernel`: ``cache=True`` (compiled once, loaded from
``__pycache__`` afterwards), ``fastmath=False`` (bit-reproducible), ``nogil=False``,
``error_model='numpy'`` (no Python exceptions for division by zero inside kernels; kernels return
status codes instead).

``nogil=False``: the kernels run for microseconds, and releasing the GIL around each of them
(about 20 calls per input message) handed it to any other Python thread that wanted it, and the
filter loop then waited to get it back. With Zenoh callback threads in the node this ping-pong
was measured to cost about a sixth of the node's capacity (perf/README.md). Numba's cache index
does not see a change of these flags: after editing ``_POLICY``, delete the ``*.nbi``/``*.nbc``
files under ``__pycache__`` (a clean checkout, as in CI, has none).
"""

from __future__ import annotations

from numba import njit

_POLICY = dict(cache=True, fastmath=False, nogil=False, error_model="numpy")


def kernel(fn):
    """Compile ``fn`` with the project's Numba policy."""
    return njit(**_POLICY)(fn)


# Status codes returned by kernels (never raised).
OK = 0
ERR_NOT_POSITIVE = 1  # a variance or pivot became non-positive or non-finite
ERR_SHAPE = 2  # inconsistent array sizes
ERR_NONFINITE = 3  # a NaN or Inf in an input


def inline_kernel(fn):
    """:func:`kernel` inlined into its callers at Numba IR level (``inline='always'``): for the
    helpers of :mod:`radical_rt.fastpath` that take the tuple of engine arrays, whose reference
    counting per call would otherwise cost more than their arithmetic."""
    return njit(inline="always", **_POLICY)(fn)
