"""Rotation kernels against scipy.spatial.transform.Rotation; contract frames, geometry, layout.

Every random input is seeded (SEED below); scipy is the oracle for the conventions of CONTRACT §1.3
(scalar-last quaternions, Hamilton product, v_X = R(q_X_from_Y) v_Y).
"""

from __future__ import annotations

import math

import mpmath
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from radical_rt.contract import geometry as geo
from radical_rt.contract.state import LAYOUT, N_STATES, StateLayout
from radical_rt.kernels import rotation as rot

SEED = 20240517
N_RANDOM = 300


def rng(offset=0):
    return np.random.default_rng(SEED + offset)


def random_quats(n, offset=0):
    return Rotation.random(n, random_state=SEED + offset).as_quat()


def same_rotation_quat(q, p, atol=1e-14):
    """Quaternions equal up to sign."""
    s = 1.0 if np.dot(q, p) >= 0 else -1.0
    np.testing.assert_allclose(q, s * np.asarray(p), rtol=0, atol=atol)


def special_rotvecs():
    """Small angles, the Taylor-branch boundary (1e-6), angles near and at π, and > π."""
    axes = [np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), np.array([0, 0, 1.0]),
            np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])]
    angles = [0.0, 1e-15, 1e-12, 1e-9, 3e-7, 1e-6 * (1 - 1e-12), 1e-6, 1e-6 * (1 + 1e-12), 1e-4,
              0.1, 1.0, math.pi / 2, math.pi - 1e-4, math.pi - 1e-9, math.pi, 4.0,
              2 * math.pi - 0.1]
    return [a * ax for ax in axes for a in angles]


# --------------------------------------------------------------------------- quaternion kernels
def test_quat_to_dcm_matches_scipy():
    for q in random_quats(N_RANDOM):
        np.testing.assert_allclose(rot.quat_to_dcm(q), Rotation.from_quat(q).as_matrix(),
                                   rtol=0, atol=1e-15)
        out = np.empty((3, 3))
        rot.quat_to_dcm_into(q, out)
        np.testing.assert_array_equal(out, rot.quat_to_dcm(q))


def test_quat_mul_matches_scipy_product_and_composition():
    qs, ps = random_quats(N_RANDOM, 1), random_quats(N_RANDOM, 2)
    for q, p in zip(qs, ps, strict=True):
        qp = rot.quat_mul(q, p)
        same_rotation_quat(qp, (Rotation.from_quat(q) * Rotation.from_quat(p)).as_quat())
        # contract: q_X_from_Z = q_X_from_Y ⊗ q_Y_from_Z, i.e. R(q ⊗ p) = R(q) R(p)
        np.testing.assert_allclose(rot.quat_to_dcm(qp), rot.quat_to_dcm(q) @ rot.quat_to_dcm(p),
                                   atol=1e-14)
    # pinned by hand: 90° about z then 90° about x (R_z R_x)
    qz = np.array([0, 0, math.sqrt(0.5), math.sqrt(0.5)])
    qx = np.array([math.sqrt(0.5), 0, 0, math.sqrt(0.5)])
    np.testing.assert_allclose(rot.quat_mul(qz, qx), [0.5, 0.5, 0.5, 0.5], atol=1e-16)
    # order matters and the product is not commutative
    assert not np.allclose(rot.quat_mul(qz, qx), rot.quat_mul(qx, qz))


def test_quat_conj_is_inverse():
    for q in random_quats(50, 3):
        np.testing.assert_allclose(rot.quat_to_dcm(rot.quat_conj(q)),
                                   Rotation.from_quat(q).inv().as_matrix(), atol=1e-15)
        same_rotation_quat(rot.quat_mul(q, rot.quat_conj(q)), [0, 0, 0, 1.0])


def test_quat_normalize_inplace():
    g = rng(4)
    for _ in range(100):
        q = g.standard_normal(4) * 10.0 ** g.uniform(-3, 3)
        q0 = q.copy()
        assert rot.quat_normalize_inplace(q) == 0
        assert abs(np.linalg.norm(q) - 1) < 1e-15 and q[3] >= 0
        same_rotation_quat(q, Rotation.from_quat(q0).as_quat())
    for bad in (np.zeros(4), np.array([np.nan, 0, 0, 1.0]), np.array([np.inf, 0, 0, 1.0])):
        assert rot.quat_normalize_inplace(bad) == 3


def test_dcm_to_quat_matches_scipy_all_branches():
    mats = list(Rotation.random(N_RANDOM, random_state=SEED + 5).as_matrix())
    mats += [Rotation.from_rotvec(v).as_matrix() for v in special_rotvecs()]
    for m in mats:  # random + rotations near π about x, y, z (each Shepperd branch)
        q = rot.dcm_to_quat(m)
        assert abs(np.linalg.norm(q) - 1) < 1e-15 and q[3] >= 0
        same_rotation_quat(q, Rotation.from_matrix(m).as_quat(), atol=1e-15)
        np.testing.assert_allclose(rot.quat_to_dcm(q), m, atol=1e-15)


def test_rotvec_to_quat_matches_scipy_including_small_and_large_angles():
    vecs = list(rng(6).standard_normal((N_RANDOM, 3)) * 1.5) + special_rotvecs()
    for phi in vecs:
        q_ref = Rotation.from_rotvec(phi).as_quat()  # same sign convention: w = cos(|φ|/2)
        q = rot.rotvec_to_quat(phi)
        np.testing.assert_allclose(q, q_ref, rtol=2e-15, atol=1e-300)
        np.testing.assert_allclose(rot.rotvec_to_dcm(phi), Rotation.from_rotvec(phi).as_matrix(),
                                   atol=2e-15)
        out = np.empty(4)
        rot.rotvec_to_quat_into(phi, out)
        np.testing.assert_array_equal(out, q)


def test_quat_to_rotvec_matches_scipy():
    quats = list(random_quats(N_RANDOM, 7))
    quats += [Rotation.from_rotvec(v).as_quat() for v in special_rotvecs()]
    quats += [-q for q in quats[:50]]  # w < 0: same rotation, angle still in [0, π]
    for q in quats:
        phi, phi_ref = rot.quat_to_rotvec(q), Rotation.from_quat(q).as_rotvec()
        assert np.linalg.norm(phi) <= math.pi + 1e-15
        if abs(np.linalg.norm(phi_ref) - math.pi) < 1e-6:  # ±φ are the same rotation at π
            phi_ref = phi_ref * np.sign(np.dot(phi, phi_ref) or 1.0)
        np.testing.assert_allclose(phi, phi_ref, rtol=4e-15, atol=1e-300)


@pytest.mark.parametrize("angle", [1e-300, 1e-12, 1e-9, 5e-8, 1.9e-7, 2.1e-7, 1e-6, 1e-3])
def test_quat_to_rotvec_small_angles_are_relatively_exact(angle):
    """Against a 40-digit reference: no loss of relative precision near zero (Taylor branch)."""
    mpmath.mp.dps = 40
    axis = np.array([0.48, -0.6, 0.64])
    s = mpmath.sin(mpmath.mpf(angle) / 2)
    w = float(mpmath.cos(mpmath.mpf(angle) / 2))
    q = np.array([float(s * mpmath.mpf(a)) for a in axis] + [w])
    sn = mpmath.sqrt(sum(mpmath.mpf(float(x)) ** 2 for x in q[:3]))
    k = 2 * mpmath.atan2(sn, mpmath.mpf(q[3])) / sn  # exact rotation vector of the rounded q
    ref = np.array([float(k * mpmath.mpf(float(x))) for x in q[:3]])
    np.testing.assert_allclose(rot.quat_to_rotvec(q), ref, rtol=1e-15, atol=0)


def test_quat_rotate_and_skew():
    g = rng(8)
    vs, us = g.standard_normal((100, 3)), g.standard_normal((100, 3))
    for q, v, u in zip(random_quats(100, 9), vs, us, strict=True):
        np.testing.assert_allclose(rot.quat_rotate(q, v), Rotation.from_quat(q).apply(v),
                                   atol=1e-14)
        np.testing.assert_allclose(rot.skew(v) @ u, np.cross(v, u), atol=1e-14)
        np.testing.assert_array_equal(rot.skew(v), -rot.skew(v).T)


def test_attitude_error_convention():
    """conventions.py: R_true = R(dθ)ᵀ R_est, folded in with q ← rotvec_to_quat(−dθ) ⊗ q."""
    q_est = random_quats(1, 10)[0]
    dtheta = np.array([1e-3, -2e-3, 5e-4])
    r_true = Rotation.from_rotvec(dtheta).as_matrix().T @ Rotation.from_quat(q_est).as_matrix()
    q_new = rot.quat_mul(rot.rotvec_to_quat(-dtheta), q_est)
    np.testing.assert_allclose(rot.quat_to_dcm(q_new), r_true, atol=1e-15)


# --------------------------------------------------------------------------- contract frames
def test_nominal_triads_match_contract_and_are_right_handed():
    W = np.array([[1, -1, -1, 1], [1, 1, -1, -1], [1, 1, 1, 1]]) / math.sqrt(3)
    U = np.array([[-1, -1, 1, 1], [1, -1, -1, 1], [0, 0, 0, 0]]) / math.sqrt(2)
    V = np.array([[-1, 1, 1, -1], [-1, -1, 1, 1], [2, 2, 2, 2]]) / math.sqrt(6)
    np.testing.assert_allclose(geo.W_NOM, W, rtol=0, atol=1e-16)
    np.testing.assert_allclose(geo.U_NOM, U, rtol=0, atol=1e-16)
    np.testing.assert_allclose(geo.V_NOM, V, rtol=0, atol=1e-16)
    for i in range(4):
        T = np.column_stack([geo.U_NOM[:, i], geo.V_NOM[:, i], geo.W_NOM[:, i]])
        np.testing.assert_allclose(T.T @ T, np.eye(3), atol=1e-15)
        assert np.linalg.det(T) == pytest.approx(1.0, abs=1e-15)
        np.testing.assert_allclose(np.cross(T[:, 0], T[:, 1]), T[:, 2], atol=1e-15)
    p = np.array([1.0, -1.0, 1.0, -1.0]) / 2
    np.testing.assert_array_equal(geo.P_NOM, p)
    np.testing.assert_allclose(geo.W_NOM @ p, 0.0, atol=1e-16)
    np.testing.assert_allclose(geo.W_NOM @ geo.W_NOM.T, 4.0 / 3.0 * np.eye(3), atol=1e-15)
    np.testing.assert_allclose(geo.Geometry().N, p[:, None], atol=1e-15)


def test_tracker_mountings_exact():
    R1 = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])
    R2 = np.array([[0, -1.0, 0], [-1.0, 0, 0], [0, 0, -1.0]])
    np.testing.assert_array_equal(geo.R_ST1_FROM_BODY, R1)
    np.testing.assert_array_equal(geo.R_ST2_FROM_BODY_NOM, R2)
    for R in (R1, R2):  # proper rotations, boresight (tracker +z) along −z body
        assert np.linalg.det(R) == 1.0 and np.array_equal(R @ R.T, np.eye(3))
        np.testing.assert_array_equal(R.T @ [0, 0, 1.0], [0, 0, -1.0])
    rel = Rotation.from_matrix(R2 @ R1.T).as_rotvec()  # st2 from st1: 90° about the boresight
    np.testing.assert_allclose(np.abs(rel), [0, 0, math.pi / 2], atol=1e-15)
    # the contract's true ST2 mounting with phi2 = 0 is the nominal one
    np.testing.assert_allclose(R2 @ Rotation.from_rotvec(np.zeros(3)).as_matrix().T, R2)


# --------------------------------------------------------------------------- geometry validation
def test_geometry_rejects_bad_input():
    with pytest.raises(geo.GeometryError, match="right-handed"):
        geo.Geometry(V=-geo.V_NOM)  # left-handed triads
    with pytest.raises(geo.GeometryError, match="n ≥ 4"):
        geo.Geometry(W=geo.W_NOM[:, :3], U=geo.U_NOM[:, :3], V=geo.V_NOM[:, :3])
    az = np.linspace(0, 2 * math.pi, 5)[:4]
    W_flat = np.vstack([np.cos(az), np.sin(az), np.zeros(4)])  # all axes in the xy-plane
    U_flat, V_flat = geo.triads_from_axes(W_flat)
    with pytest.raises(geo.GeometryError, match="rank"):
        geo.Geometry(W=W_flat, U=U_flat, V=V_flat)
    with pytest.raises(geo.GeometryError, match="orthonormal"):
        geo.Geometry(U=2 * geo.U_NOM)
    with pytest.raises(geo.GeometryError, match="rotation"):
        geo.Geometry(R_st1_from_body=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(geo.GeometryError, match="finite"):
        geo.Geometry(W=np.full((3, 4), np.nan))


@pytest.mark.parametrize("n", [5, 6])
def test_geometry_accepts_more_gyros(n):
    W = rng(11 + n).standard_normal((3, n))
    W[:, 0] = [0.0, 0.0, 1.0]  # triads_from_axes special case: w parallel to z
    W /= np.linalg.norm(W, axis=0)
    U, V = geo.triads_from_axes(W)
    g = geo.Geometry(W=W, U=U, V=V)
    assert g.n_gyro == n
    N = g.N
    assert N.shape == (n, n - 3)
    np.testing.assert_allclose(W @ N, 0.0, atol=1e-14)
    np.testing.assert_allclose(N.T @ N, np.eye(n - 3), atol=1e-14)
    N2 = geo.null_basis(W, reference=N)  # continuity: the reference basis is reproduced
    np.testing.assert_allclose(N2, N, atol=1e-13)


# --------------------------------------------------------------------------- state layout
def test_state_layout_tiles_in_order():
    names = [b.name for b in LAYOUT]
    assert names == ["att", "b", "lam", "mu", "du", "dv", "phi2"]
    covered = [i for b in LAYOUT for i in range(N_STATES)[b.slice]]
    assert covered == list(range(N_STATES)) and N_STATES == 26
    assert [LAYOUT.block(k).size for k in names] == [3, 4, 4, 4, 4, 4, 3]
    assert LAYOUT.gyro_params == slice(3, 23) and LAYOUT.n_params == 23
    big = StateLayout(6)
    assert [i for b in big for i in range(big.n_states)[b.slice]] == list(range(big.n_states))
    assert big.n_states == 3 + 5 * 6 + 3
    with pytest.raises(ValueError):
        StateLayout(3)
