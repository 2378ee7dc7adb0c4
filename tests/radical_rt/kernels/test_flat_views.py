"""The compiled views of radical_rt.kernels.flat_views (memory they do not own) against their
NumPy forms: the same elements, writes reaching the buffer, borrow() of C-contiguous and strided
arrays, keep() holding a kernel's own array alive for its borrowed view."""

from __future__ import annotations

import numpy as np
from numba import njit

from radical_rt.kernels.flat_views import borrow, keep, view1, view2, view3


@njit(cache=False)
def _compiled_views(buf, lay):
    a, b, c = view1(buf, lay, 0), view2(buf, lay, 1), view3(buf, lay, 2)
    b[1, 2] += 100.0  # through the view, into buf
    return a.copy(), b.copy(), c.copy(), a.shape[0], b.shape, c.shape


@njit(cache=False)
def _borrowed(a, s):
    v, w = borrow(a), borrow(s)
    v[0, 0] = -1.0
    return v.sum(), w.sum(), v.shape


def test_compiled_views_equal_numpy_views_and_write_through():
    rng = np.random.default_rng(7)
    buf = rng.normal(size=64)
    lay = np.array([[3, 5, 0, 0], [10, 3, 4, 0], [30, 2, 3, 4]], np.int64)
    want = [view1(buf, lay, 0).copy(), view2(buf, lay, 1).copy(), view3(buf, lay, 2).copy()]
    assert want[1].shape == (3, 4) and want[2].shape == (2, 3, 4)
    before = buf.copy()
    a, b, c, n, shape_b, shape_c = _compiled_views(buf, lay)
    np.testing.assert_array_equal(a, want[0])
    np.testing.assert_array_equal(c, want[2])
    assert n == 5 and shape_b == (3, 4) and shape_c == (2, 3, 4)
    want[1][1, 2] += 100.0
    np.testing.assert_array_equal(b, want[1])
    changed = np.flatnonzero(buf != before)
    assert changed.tolist() == [10 + 1 * 4 + 2]  # the one element written, nothing else


def test_borrow_c_contiguous_and_strided():
    a = np.arange(12.0).reshape(3, 4)
    strided = np.arange(20.0)[::2]  # not C-contiguous: passed on as it is
    assert borrow(a) is a  # the Python form
    total, s_total, shape = _borrowed(a, strided)
    assert a[0, 0] == -1.0 and total == a.sum() and s_total == strided.sum() and shape == (3, 4)


@njit(cache=False)
def _own_borrowed(n, rounds):
    """A kernel's own array seen through a borrowed view while the kernel allocates (and frees)
    arrays of the same size many times, which would reuse its memory had it been released after
    its last use; kept to the end."""
    own = np.full(n, 1.0)
    v = borrow(own)
    junk = 0.0
    for r in range(rounds):
        tmp = np.full(n, 2.0 + r)
        junk += tmp[0]
    total = v.sum()
    keep(own)
    return total, junk


def test_keep_holds_the_owner_of_a_borrowed_view():
    total, junk = _own_borrowed(64, 200)
    assert total == 64.0
    assert junk == sum(2.0 + r for r in range(200))
    assert keep(np.zeros(3)) is None  # the Python form does nothing
