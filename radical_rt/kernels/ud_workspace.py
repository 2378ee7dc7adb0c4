"""Preallocated work arrays for the UD kernels of :mod:`radical_rt.kernels.ud` and
:mod:`radical_rt.kernels.ud_time` (plain Python, no Numba).

One :class:`UDWorkspace` per filter instance; kernels take its arrays as ``*_work`` arguments so
no kernel allocates per call. Also importable as ``radical_rt.kernels.ud.UDWorkspace``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class UDWorkspace:
    """Every work array the UD kernels need for n states, preallocated once (plain Python).

    n: states; m_att: leading (attitude) block size; r_max: max columns of G in MWGS (default n);
    z_max: max rows of a vector measurement to whiten with :func:`decorrelate`.
    """

    n: int
    m_att: int = 3
    r_max: int | None = None
    z_max: int = 3
    f: np.ndarray = field(init=False, repr=False)  # (n,)  Uᵀh
    v: np.ndarray = field(init=False, repr=False)  # (n,)  D Uᵀh
    k: np.ndarray = field(init=False, repr=False)  # (n,)  Kalman gain
    a: np.ndarray = field(init=False, repr=False)  # (n,)  Agee-Turner vector copy
    var: np.ndarray = field(init=False, repr=False)  # (n,)  variances()
    Y: np.ndarray = field(init=False, repr=False)  # (n, n + r_max)  MWGS
    Dw: np.ndarray = field(init=False, repr=False)  # (n + r_max,)
    c: np.ndarray = field(init=False, repr=False)  # (n + r_max,)
    struct: np.ndarray = field(init=False, repr=False)  # (m_att, n + m_att)
    L: np.ndarray = field(init=False, repr=False)  # (z_max, z_max)  decorrelate
    H_w: np.ndarray = field(init=False, repr=False)  # (z_max, n)  whitened H
    z_w: np.ndarray = field(init=False, repr=False)  # (z_max,)  whitened z

    def __post_init__(self) -> None:
        n = self.n
        if self.r_max is None:
            self.r_max = n
        if n < 1 or not 1 <= self.m_att <= n or self.r_max < 0 or self.z_max < 1:
            raise ValueError(f"bad UDWorkspace sizes n={n} m_att={self.m_att} r_max={self.r_max}")
        w = n + self.r_max
        self.f, self.v, self.k, self.a, self.var = (np.zeros(n) for _ in range(5))
        self.Y, self.Dw, self.c = np.zeros((n, w)), np.zeros(w), np.zeros(w)
        self.struct = np.zeros((self.m_att, n + self.m_att))
        self.L, self.H_w, self.z_w = (np.zeros((self.z_max, self.z_max)),
                                      np.zeros((self.z_max, n)), np.zeros(self.z_max))
