"""The single Numba policy of RADICAL-RT.

Every compiled kernel is declared with :func:`kernel`: ``cache=True`` (compiled once, loaded from
``__pycache__`` afterwards), ``fastmath=False`` (bit-reproducible), ``nogil=True`` (Zenoh and
dashboard threads keep running while a kernel works), ``error_model='numpy'`` (no Python exceptions
for division by zero inside kernels; kernels return status codes instead).
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
