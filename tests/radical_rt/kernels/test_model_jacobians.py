"""The masked pseudo-inverse and the star-tracker residual and Jacobians against scipy.

(The gyro increment and parity Jacobians, and the attitude-error propagation, of the engine's
internal parametrization are tested in test_engine_model.py.)"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from radical_rt.contract.conventions import ARCSEC
from radical_rt.contract.geometry import Geometry
from radical_rt.kernels.model import masked_pinv
from radical_rt.kernels.tracker_model import tracker_residual

GEO = Geometry()
N_G = GEO.n_gyro


def test_masked_pinv_uses_only_active_gyros():
    Wt = GEO.W.copy()
    act = np.array([True, True, False, True])
    Minv, Gp = np.zeros((3, 3)), np.zeros((3, 4))
    assert masked_pinv(Wt, act, Minv, Gp) == 3
    np.testing.assert_allclose(Gp[:, 2], 0)
    np.testing.assert_allclose(Gp[:, act] @ Wt[:, act].T, np.eye(3), atol=1e-14)
    assert masked_pinv(Wt, np.array([True, False, False, True]), Minv, Gp) == -1


@pytest.mark.parametrize("j", [1, 2])
def test_tracker_residual_and_jacobians(j):
    """r = −rotvec(R_meas R̂ᵀ) ≈ H_att δθ + H_phi δφ for the contract's mountings (scipy oracle)."""
    rng = np.random.default_rng(11 + j)
    R_nom = GEO.R_st1_from_body if j == 1 else GEO.R_st2_from_body_nom
    phi_hat = rng.normal(size=3) * 1500 * ARCSEC if j == 2 else np.zeros(3)
    dth = rng.normal(size=3) * 20 * ARCSEC
    dphi = rng.normal(size=3) * 20 * ARCSEC if j == 2 else np.zeros(3)
    R_b_est = Rotation.random(random_state=j)
    R_b_true = Rotation.from_rotvec(dth).inv() * R_b_est
    # CONTRACT §1.4: R_st2_from_body = R_nom @ R(phi2)ᵀ
    R_meas = Rotation.from_matrix(R_nom @ Rotation.from_rotvec(phi_hat + dphi).as_matrix().T) * R_b_true
    r, Ha, Hp = np.zeros(3), np.zeros((3, 3)), np.zeros((3, 3))
    tracker_residual(R_meas.as_quat(), R_b_est.as_quat(), R_nom, phi_hat, j == 2, r, Ha, Hp)
    pred = Ha @ dth + Hp @ dphi
    np.testing.assert_allclose(r, pred, atol=2e-3 * np.linalg.norm(r))
    if j == 1:
        np.testing.assert_array_equal(Hp, 0)
        np.testing.assert_array_equal(Ha, R_nom)
