"""Sensor geometry: SIRU sense-axis triads (W, U, V), parity (null-space) basis, tracker mountings.

Nominal values are those of CONTRACT §1.4. Geometry is configuration: :class:`Geometry` accepts
any number n ≥ 4 of sense axes with their in-plane axes, validated on construction.
All matrices are 3×n with one column per gyro, body-frame components.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

S3, S2, S6 = np.sqrt(3.0), np.sqrt(2.0), np.sqrt(6.0)

#: Nominal octahedral sense axes w_i (columns, body frame), gyros A..D.
W_NOM = np.array([[1.0, -1.0, -1.0, 1.0], [1.0, 1.0, -1.0, -1.0], [1.0, 1.0, 1.0, 1.0]]) / S3
#: In-plane axes u_i (columns) with u_i × v_i = w_i.
U_NOM = np.array([[-1.0, -1.0, 1.0, 1.0], [1.0, -1.0, -1.0, 1.0], [0.0, 0.0, 0.0, 0.0]]) / S2
#: In-plane axes v_i (columns).
V_NOM = np.array([[-1.0, 1.0, 1.0, -1.0], [-1.0, -1.0, 1.0, 1.0], [2.0, 2.0, 2.0, 2.0]]) / S6
#: Nominal parity vector: W_NOM @ P_NOM = 0, unit norm.
P_NOM = np.array([1.0, -1.0, 1.0, -1.0]) / 2.0

#: ST1 mounting, the body reference: v_st1 = R_ST1_FROM_BODY @ v_body (exact).
R_ST1_FROM_BODY = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
#: ST2 nominal mounting (boresight −z body, rotated 90° about it relative to ST1).
R_ST2_FROM_BODY_NOM = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])

GYRO_NAMES = ("A", "B", "C", "D")


class GeometryError(ValueError):
    """Raised when a configured geometry is not a valid set of sense-axis triads."""


def null_basis(W: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
    """Orthonormal basis (n, n−3) of the null space of W (3×n): W @ N = 0, NᵀN = I.

    With ``reference`` (n, n−3), the basis is the projection of the reference onto null(W),
    orthonormalized, which makes it continuous as W changes slowly (and, for n = 4 with the
    nominal reference, equal to the contract's p = (1, −1, 1, −1)/2 at nominal geometry).
    """
    W = np.asarray(W, dtype=float)
    n = W.shape[1]
    if reference is None:
        _, _, vt = np.linalg.svd(W)
        basis = vt[3:].T
    else:
        proj = np.eye(n) - W.T @ np.linalg.solve(W @ W.T, W)
        basis = proj @ np.asarray(reference, dtype=float).reshape(n, n - 3)
    q, r = np.linalg.qr(basis)
    return q * np.sign(np.where(np.diag(r) == 0, 1.0, np.diag(r)))


def triads_from_axes(W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Complete each unit sense axis w_i to a right-handed triad (u_i, v_i, w_i), u_i × v_i = w_i.

    u_i is horizontal (z component 0, along z × w_i) unless w_i is parallel to z, then along x.
    Returns (U, V), both 3×n. Once chosen, U and V must not change (they define du, dv).
    """
    W = np.asarray(W, dtype=float)
    U = np.empty_like(W)
    V = np.empty_like(W)
    for i in range(W.shape[1]):
        w = W[:, i] / np.linalg.norm(W[:, i])
        u = np.cross([0.0, 0.0, 1.0], w)
        if np.linalg.norm(u) < 1e-9:
            u = np.array([1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        U[:, i] = u
        V[:, i] = np.cross(w, u)
    return U, V


@dataclass(frozen=True)
class Geometry:
    """SIRU triads and tracker mountings.

    W, U, V: (3, n) body-frame unit columns, (u_i, v_i, w_i) right-handed orthonormal, n ≥ 4, and
    every 3-axis subset is not required but W must have rank 3. ``N`` (n, n−3) is the nominal parity
    basis. ``R_st1_from_body`` and ``R_st2_from_body_nom`` are proper rotations (3, 3).
    """

    W: np.ndarray = field(default_factory=lambda: W_NOM.copy())
    U: np.ndarray = field(default_factory=lambda: U_NOM.copy())
    V: np.ndarray = field(default_factory=lambda: V_NOM.copy())
    R_st1_from_body: np.ndarray = field(default_factory=lambda: R_ST1_FROM_BODY.copy())
    R_st2_from_body_nom: np.ndarray = field(default_factory=lambda: R_ST2_FROM_BODY_NOM.copy())

    def __post_init__(self) -> None:
        for name in ("W", "U", "V", "R_st1_from_body", "R_st2_from_body_nom"):
            object.__setattr__(self, name, np.ascontiguousarray(getattr(self, name), dtype=float))
        validate(self)

    @property
    def n_gyro(self) -> int:
        """Number of sense axes n."""
        return int(self.W.shape[1])

    @property
    def N(self) -> np.ndarray:
        """Nominal parity basis (n, n−3); equals P_NOM[:, None] for the contract's geometry."""
        ref = P_NOM[:, None] if self.n_gyro == 4 else None
        return null_basis(self.W, ref)


def validate(g: Geometry, tol: float = 1e-9) -> None:
    """Check shapes, unit/orthogonal right-handed triads, rank and proper mountings.

    Raises :class:`GeometryError` with a message naming the offending item.
    """
    W, U, V = g.W, g.U, g.V
    if W.ndim != 2 or W.shape[0] != 3 or W.shape[1] < 4:
        raise GeometryError(f"W must be 3×n with n ≥ 4, got shape {W.shape}")
    if U.shape != W.shape or V.shape != W.shape:
        raise GeometryError(f"U {U.shape} and V {V.shape} must have W's shape {W.shape}")
    if not (np.all(np.isfinite(W)) and np.all(np.isfinite(U)) and np.all(np.isfinite(V))):
        raise GeometryError("W, U, V must be finite")
    for i in range(W.shape[1]):
        triad = np.column_stack([U[:, i], V[:, i], W[:, i]])
        if np.max(np.abs(triad.T @ triad - np.eye(3))) > tol:
            raise GeometryError(f"gyro {i}: (u, v, w) is not orthonormal")
        if np.max(np.abs(np.cross(U[:, i], V[:, i]) - W[:, i])) > tol:
            raise GeometryError(f"gyro {i}: u × v ≠ w (triad must be right-handed)")
    if np.linalg.matrix_rank(W, tol=1e-6) < 3:
        raise GeometryError("W has rank < 3: the sense axes do not span body space")
    for name in ("R_st1_from_body", "R_st2_from_body_nom"):
        m = getattr(g, name)
        if m.shape != (3, 3) or np.max(np.abs(m @ m.T - np.eye(3))) > tol or np.linalg.det(m) < 0:
            raise GeometryError(f"{name} must be a proper 3×3 rotation matrix")
