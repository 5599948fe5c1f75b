"""SO(3)/SE(3) operations against scipy.spatial.transform as an independent reference."""

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from lerobot_actionflow.core import geometry as g

f64 = torch.float64


def _axes(n: int, seed: int) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return torch.nn.functional.normalize(torch.randn(n, 3, generator=gen, dtype=f64), dim=-1)


# Angles where naive formulas lose precision: 0 (division by sin), pi (sin vanishes, axis ambiguous).
EDGE_ANGLES = [0.0, 1e-12, 1e-8, 1e-5, 1e-3, 0.5, math.pi / 2, math.pi - 1e-3, math.pi - 1e-6, math.pi - 1e-9]


def test_exp_matches_scipy_on_random_vectors():
    omega = torch.randn(2000, 3, generator=torch.Generator().manual_seed(0), dtype=f64) * 2.0
    ref = Rotation.from_rotvec(omega.numpy()).as_matrix()
    np.testing.assert_allclose(g.so3_exp(omega).numpy(), ref, atol=1e-12)


def test_log_matches_scipy_on_random_rotations():
    rots = Rotation.random(2000, random_state=1)
    got = g.so3_log(torch.from_numpy(rots.as_matrix())).numpy()
    np.testing.assert_allclose(got, rots.as_rotvec(), atol=1e-10)


@pytest.mark.parametrize("angle", EDGE_ANGLES)
def test_exp_log_near_zero_and_pi(angle):
    """Exp and Log stay accurate at the angles where the textbook formulas divide by ~0."""
    omega = _axes(64, 2) * angle
    rot = g.so3_exp(omega)
    np.testing.assert_allclose(rot.numpy(), Rotation.from_rotvec(omega.numpy()).as_matrix(), atol=1e-12)
    log = g.so3_log(rot)
    assert torch.allclose(log.norm(dim=-1), torch.full((64,), angle, dtype=f64), atol=1e-9)
    np.testing.assert_allclose(g.so3_exp(log).numpy(), rot.numpy(), atol=1e-12)
    if angle < math.pi - 1e-6:  # at pi the axis sign is arbitrary; elsewhere log recovers omega itself
        np.testing.assert_allclose(log.numpy(), omega.numpy(), atol=1e-9)


def test_exp_of_log_is_identity_in_float32():
    rots = torch.from_numpy(Rotation.random(1000, random_state=3).as_matrix()).float()
    assert (g.so3_exp(g.so3_log(rots)) - rots).abs().max() < 1e-5


def test_log_exactly_pi():
    rot = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=f64))  # pi about x
    log = g.so3_log(rot)
    assert torch.allclose(log.abs(), torch.tensor([math.pi, 0.0, 0.0], dtype=f64), atol=1e-12)


def test_exp_log_gradients_finite_at_zero():
    omega = torch.zeros(4, 3, dtype=f64, requires_grad=True)
    g.so3_log(g.so3_exp(omega)).sum().backward()
    assert torch.isfinite(omega.grad).all()


def test_quaternion_conversions_match_scipy():
    rots = Rotation.random(500, random_state=4)
    quat = g.matrix_to_quaternion(torch.from_numpy(rots.as_matrix())).numpy()
    ref = rots.as_quat(scalar_first=True)
    ref = np.where(ref[:, :1] < 0, -ref, ref)
    np.testing.assert_allclose(quat, ref, atol=1e-12)
    np.testing.assert_allclose(
        g.quaternion_to_matrix(torch.from_numpy(ref)).numpy(), rots.as_matrix(), atol=1e-12
    )


def test_rot6d_round_trip_and_gram_schmidt():
    rots = torch.from_numpy(Rotation.random(100, random_state=5).as_matrix())
    six = g.matrix_to_rot6d(rots)
    assert torch.equal(six[:, :3], rots[:, :, 0]) and torch.equal(six[:, 3:], rots[:, :, 1])
    assert torch.allclose(g.rot6d_to_matrix(six), rots, atol=1e-12)
    # A scaled, sheared 6D vector still yields the nearest frame sharing the first column's direction.
    noisy = torch.cat([2.0 * six[:, :3], six[:, 3:] + 0.3 * six[:, :3]], -1)
    assert torch.allclose(g.rot6d_to_matrix(noisy), rots, atol=1e-12)


def test_pose9_layout():
    """[x, y, z, r00, r10, r20, r01, r11, r21]: position, then rotation columns 0 and 1."""
    rot = torch.from_numpy(Rotation.from_euler("xyz", [0.1, 0.2, 0.3]).as_matrix())
    trans = torch.tensor([1.0, 2.0, 3.0], dtype=f64)
    pose = g.rt_to_pose9(rot, trans)
    expected = [1, 2, 3, rot[0, 0], rot[1, 0], rot[2, 0], rot[0, 1], rot[1, 1], rot[2, 1]]
    assert torch.allclose(pose, torch.tensor(expected, dtype=f64))
    r, p = g.pose9_to_rt(pose)
    assert torch.allclose(r, rot, atol=1e-12) and torch.equal(p, trans)


def test_compose_inverse_apply_against_scipy():
    ra, rb = Rotation.random(2, random_state=6)
    pa, pb = np.array([0.1, -0.2, 0.3]), np.array([-1.0, 0.5, 2.0])
    t = lambda a: torch.from_numpy(np.asarray(a))  # noqa: E731
    rot, trans = g.compose(t(ra.as_matrix()), t(pa), t(rb.as_matrix()), t(pb))
    np.testing.assert_allclose(rot.numpy(), (ra * rb).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(trans.numpy(), ra.apply(pb) + pa, atol=1e-12)
    inv_r, inv_p = g.inverse(t(ra.as_matrix()), t(pa))
    np.testing.assert_allclose(inv_r.numpy(), ra.inv().as_matrix(), atol=1e-12)
    np.testing.assert_allclose(inv_p.numpy(), -ra.inv().apply(pa), atol=1e-12)
    x = np.array([0.3, 0.4, -0.5])
    np.testing.assert_allclose(g.apply(t(ra.as_matrix()), t(pa), t(x)).numpy(), ra.apply(x) + pa, atol=1e-12)
    np.testing.assert_allclose(
        g.apply_inverse(t(ra.as_matrix()), t(pa), t(x)).numpy(), ra.inv().apply(x - pa), atol=1e-12
    )
    rel_r, rel_p = g.relative(t(ra.as_matrix()), t(pa), t(rb.as_matrix()), t(pb))
    np.testing.assert_allclose(rel_r.numpy(), (ra.inv() * rb).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(rel_p.numpy(), ra.inv().apply(pb - pa), atol=1e-12)


def test_batched_over_leading_dims():
    omega = torch.randn(2, 3, 5, 3, dtype=f64)
    assert g.so3_exp(omega).shape == (2, 3, 5, 3, 3)
    assert g.so3_log(g.so3_exp(omega)).shape == (2, 3, 5, 3)
    assert g.rot6d_to_matrix(torch.randn(4, 7, 6)).shape == (4, 7, 3, 3)


def test_random_rotation_is_uniform():
    """Haar-uniform rotations: orthonormal, det +1, E[R] = 0 and the angle density (1 - cos) / pi."""
    rots = g.random_rotation((20000,), generator=torch.Generator().manual_seed(7), dtype=f64)
    eye = torch.eye(3, dtype=f64)
    assert torch.allclose(rots @ rots.transpose(-1, -2), eye.expand_as(rots), atol=1e-12)
    assert torch.allclose(torch.linalg.det(rots), torch.ones(20000, dtype=f64), atol=1e-12)
    assert rots.mean(0).abs().max() < 0.03
    angles = g.so3_log(rots).norm(dim=-1)
    # CDF of the angle under the Haar measure: (theta - sin theta) / pi; compare at a few quantiles.
    for theta in (0.5, 1.0, 2.0, 2.8):
        expected = (theta - math.sin(theta)) / math.pi
        assert abs((angles < theta).double().mean().item() - expected) < 0.015


def test_random_rotation_is_seeded():
    a = g.random_rotation((5,), generator=torch.Generator().manual_seed(1))
    b = g.random_rotation((5,), generator=torch.Generator().manual_seed(1))
    assert torch.equal(a, b)


def test_pose9_errors():
    rot = torch.from_numpy(Rotation.from_rotvec([0.0, 0.0, 0.3]).as_matrix())
    a = g.rt_to_pose9(torch.eye(3, dtype=f64), torch.zeros(3, dtype=f64))
    b = g.rt_to_pose9(rot, torch.tensor([0.0, 0.03, 0.04], dtype=f64))
    trans_err, rot_err = g.pose9_errors(a, b)
    assert torch.isclose(trans_err, torch.tensor(0.05, dtype=f64)) and torch.isclose(
        rot_err, torch.tensor(0.3, dtype=f64)
    )


def test_so3_geodesic_endpoints_and_constant_speed():
    """The geodesic the flow and the action smoothing share: R_a at t = 0, R_b at t = 1, the angle from R_a
    growing linearly with t, and the returned rotation vector the whole way's Log(R_a^T R_b)."""
    gen = torch.Generator().manual_seed(3)
    rot_a = g.random_rotation((4,), generator=gen, dtype=torch.float64)
    rot_b = g.random_rotation((4,), generator=gen, dtype=torch.float64)
    start, omega = g.so3_geodesic(rot_a, rot_b, 0.0)
    end, _ = g.so3_geodesic(rot_a, rot_b, 1.0)
    torch.testing.assert_close(start, rot_a)
    torch.testing.assert_close(end, rot_b)
    torch.testing.assert_close(omega, g.so3_log(rot_a.transpose(-1, -2) @ rot_b))
    t = torch.tensor([0.1, 0.3, 0.5, 0.9], dtype=torch.float64)[:, None]
    mid, _ = g.so3_geodesic(rot_a, rot_b, t)
    torch.testing.assert_close(g.geodesic_distance(rot_a, mid), t[:, 0] * omega.norm(dim=-1))
