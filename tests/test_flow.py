"""The rectified flows against exact solutions: Euler with the true conditional field is exact."""

import numpy as np
import pytest
import torch

from lerobot_actionflow.core import geometry as g
from lerobot_actionflow.core.flow import EuclideanFlow, SE3Flow, SE3State, integrate, time_grid

f64 = torch.float64
B, H, M = 4, 16, 2


def _pair(flow, seed: int):
    gen = torch.Generator().manual_seed(seed)
    return flow.noise(B, H, generator=gen, dtype=f64), flow.noise(B, H, generator=gen, dtype=f64)


@pytest.mark.parametrize("schedule", ["uniform", "exponential"])
@pytest.mark.parametrize("start", [0, 1, 3, 6])
def test_se3_euler_with_true_velocity_reaches_data_from_any_t(schedule, start):
    flow = SE3Flow(M)
    x0, x1 = _pair(flow, start)
    grid = time_grid(7, schedule, dtype=f64)
    xt, _ = flow.interpolate(x0, x1, grid[start].expand(B))
    x = integrate(flow, lambda x, t: flow.conditional_velocity(x, x1, t), xt, grid, start=start)
    assert (x.rot - x1.rot).abs().max() < 1e-5
    assert (x.trans - x1.trans).abs().max() < 1e-5
    assert (x.extra - x1.extra).abs().max() < 1e-5


def test_se3_true_velocity_is_exact_even_off_the_path():
    """From an arbitrary state (not on any path from x0), one step of the conditional field lands on x1."""
    flow = SE3Flow(M)
    x, x1 = _pair(flow, 11)
    t = torch.full((B,), 0.3, dtype=f64)
    out = flow.step(x, flow.conditional_velocity(x, x1, t), 0.7)
    assert (out.rot - x1.rot).abs().max() < 1e-10 and (out.trans - x1.trans).abs().max() < 1e-10


def test_se3_path_endpoints_and_geodesic():
    flow = SE3Flow(M)
    x0, x1 = _pair(flow, 2)
    for t_val, ref in ((0.0, x0), (1.0, x1)):
        xt, _ = flow.interpolate(x0, x1, torch.full((B,), t_val, dtype=f64))
        assert torch.allclose(xt.rot, ref.rot, atol=1e-10) and torch.allclose(xt.trans, ref.trans, atol=1e-12)
    # Halfway along the geodesic the angle to both ends is half the total angle.
    xh, _ = flow.interpolate(x0, x1, torch.full((B,), 0.5, dtype=f64))
    total = g.geodesic_distance(x0.rot, x1.rot)
    assert torch.allclose(g.geodesic_distance(x0.rot, xh.rot), total / 2, atol=1e-9)
    assert torch.allclose(g.geodesic_distance(xh.rot, x1.rot), total / 2, atol=1e-9)


def test_se3_target_velocity_matches_finite_differences_of_the_path():
    """The training target equals d/dt of the path, in the local frame (Eq. 3)."""
    flow = SE3Flow(M)
    x0, x1 = _pair(flow, 3)
    t = torch.full((B,), 0.37, dtype=f64)
    eps = 1e-6
    xt, target = flow.interpolate(x0, x1, t)
    xp, _ = flow.interpolate(x0, x1, t + eps)
    xm, _ = flow.interpolate(x0, x1, t - eps)
    v_world = (xp.trans - xm.trans) / (2 * eps)
    v_local = torch.einsum("bhji,bhj->bhi", xt.rot, v_world)
    omega = (g.so3_log(xt.rot.transpose(-1, -2) @ xp.rot) - g.so3_log(xt.rot.transpose(-1, -2) @ xm.rot)) / (
        2 * eps
    )
    assert torch.allclose(target[..., :3], v_local, atol=1e-6)
    assert torch.allclose(target[..., 3:6], omega, atol=1e-6)
    assert torch.allclose(target[..., 6:], (xp.extra - xm.extra) / (2 * eps), atol=1e-6)
    # And the closed form used for training equals the general conditional field on the path.
    assert torch.allclose(target, flow.conditional_velocity(xt, x1, t), atol=1e-9)


def test_se3_constant_velocity_integrates_exactly():
    """A constant body-frame twist (screw motion) is integrated exactly by the local-frame Euler step in
    rotation, and translation follows R(t) v: check against the closed form for a pure rotation + extras."""
    flow = SE3Flow(M)
    x0, _ = _pair(flow, 4)
    vel = torch.zeros(B, H, 6 + M, dtype=f64)
    vel[..., 3:6] = torch.randn(B, H, 3, dtype=f64)
    vel[..., 6:] = torch.randn(B, H, M, dtype=f64)
    x = integrate(flow, lambda x, t: vel, x0, time_grid(5, dtype=f64))
    assert torch.allclose(x.rot, x0.rot @ g.so3_exp(vel[..., 3:6]), atol=1e-10)
    assert torch.allclose(x.extra, x0.extra + vel[..., 6:], atol=1e-12)
    assert torch.equal(x.trans, x0.trans)


@pytest.mark.parametrize("frame", ["action", "eef"])
@pytest.mark.parametrize("start", [0, 2, 5])
def test_euclidean_euler_with_true_velocity_reaches_data(start, frame):
    flow = EuclideanFlow(1, frame)
    x0, x1 = _pair(flow, 5)
    grid = time_grid(6, "exponential", dtype=f64)
    xt, target = flow.interpolate(x0, x1, grid[start].expand(B))
    assert torch.allclose(flow.step(xt, target, 1.0) - xt, x1 - x0, atol=1e-12), "the straight line's"
    x = integrate(flow, lambda x, t: flow.conditional_velocity(x, x1, t), xt, grid, start=start)
    assert (x - x1).abs().max() < 1e-5


def test_euclidean_constant_velocity_integrates_exactly():
    flow = EuclideanFlow(1, "eef")
    x0, v = _pair(flow, 6)
    x = integrate(flow, lambda x, t: v, x0, time_grid(3, dtype=f64))
    assert torch.allclose(x, x0 + v, atol=1e-12)


def _turn_state(rot: np.ndarray, x: torch.Tensor) -> torch.Tensor:
    """A flat Euclidean state ``[p, a1, a2, extras]`` with its three 3-vectors turned by ``rot`` (numpy)."""
    blocks = x[..., :9].unflatten(-1, (3, 3))
    turned = torch.einsum("ij,bhkj->bhki", torch.from_numpy(rot), blocks).flatten(-2)
    return torch.cat([turned, x[..., 9:]], dim=-1)


def test_euclidean_action_frame_turns_with_the_scene():
    """``frame="action"``: turning the whole state by Q (scipy) leaves what the network reads and the
    conditional velocity it must give unchanged, and turns an Euler step of a given network output by Q; the
    velocity's norm (hence the loss) is the EEF-frame one."""
    from scipy.spatial.transform import Rotation

    flow = EuclideanFlow(2, "action")
    x, x1 = _pair(flow, 7)
    q = Rotation.random(random_state=3).as_matrix()
    t = torch.full((B,), 0.3, dtype=f64)
    assert torch.allclose(flow.network_input(_turn_state(q, x)), flow.network_input(x), atol=1e-12)
    u = flow.conditional_velocity(x, x1, t)
    assert torch.allclose(flow.conditional_velocity(_turn_state(q, x), _turn_state(q, x1), t), u, atol=1e-10)
    assert torch.allclose(u.norm(dim=-1), ((x1 - x) / 0.7).norm(dim=-1), atol=1e-10)
    v = torch.randn_like(x)
    stepped = flow.step(_turn_state(q, x), v, 0.25)
    assert torch.allclose(stepped, _turn_state(q, flow.step(x, v, 0.25)), atol=1e-12)
    # An exact rotation's 6D part reads as the identity's: its own frame is itself.
    pose = torch.from_numpy(Rotation.random(B * H, random_state=4).as_matrix()).reshape(B, H, 3, 3)
    state = flow.from_poses(SE3State(pose, torch.randn(B, H, 3, dtype=f64), torch.zeros(B, H, 2, dtype=f64)))
    identity6d = torch.tensor([1.0, 0, 0, 0, 1, 0], dtype=f64)
    assert torch.allclose(flow.network_input(state)[..., :6], identity6d.expand(B, H, 6), atol=1e-12)
    assert flow.network_input(state).shape[-1] == flow.network_input_dim == 8
    with pytest.raises(ValueError, match="frame='world'"):
        EuclideanFlow(1, "world")


def test_euclidean_poses_round_trip():
    flow = EuclideanFlow(1)
    rot = g.random_rotation((B, H), dtype=f64)
    state = SE3State(rot, torch.randn(B, H, 3, dtype=f64), torch.randn(B, H, 1, dtype=f64))
    back = flow.to_poses(flow.from_poses(state))
    assert torch.allclose(back.rot, rot, atol=1e-12) and torch.equal(back.trans, state.trans)


def test_time_grids():
    uni = time_grid(4)
    assert torch.allclose(uni, torch.tensor([0.0, 0.25, 0.5, 0.75, 1.0]))
    exp = time_grid(4, "exponential", rate=3.0, dtype=f64)
    steps = exp.diff()
    assert exp[0] == 0 and exp[-1] == 1 and (steps > 0).all()
    assert (steps.diff() < 0).all(), "exponential grid takes shorter steps towards the data (t = 1)"
    with pytest.raises(ValueError, match="num_steps=0"):
        time_grid(0)
    with pytest.raises(ValueError, match="schedule='cubic'"):
        time_grid(3, "cubic")


def test_noise_distributions():
    flow = SE3Flow(1)
    x = flow.noise(2000, 4, generator=torch.Generator().manual_seed(0), dtype=f64)
    assert torch.allclose(
        x.rot @ x.rot.transpose(-1, -2), torch.eye(3, dtype=f64).expand_as(x.rot), atol=1e-12
    )
    assert abs(x.trans.mean().item()) < 0.03 and abs(x.trans.std().item() - 1) < 0.03
    assert x.rot.mean((0, 1)).abs().max() < 0.03  # uniform on SO(3): zero mean matrix


@pytest.mark.parametrize("std", [0.2, 0.5])
def test_concentrated_rotation_noise(std):
    """rotation_noise_std: rotations Exp(std * N(0, I)), checked against scipy's rotation vectors: the angle
    follows a chi distribution with 3 degrees of freedom (mean 2 sqrt(2 / pi) std), the axis is isotropic."""
    from scipy.spatial.transform import Rotation

    flow = SE3Flow(1, rotation_noise_std=std)
    x = flow.noise(5000, 4, generator=torch.Generator().manual_seed(1), dtype=f64)
    rotvec = Rotation.from_matrix(x.rot.reshape(-1, 3, 3).numpy()).as_rotvec()  # [N, 3]
    assert abs(np.linalg.norm(rotvec, axis=1).mean() / (2 * np.sqrt(2 / np.pi) * std) - 1) < 0.02
    assert np.abs(rotvec.std(0) / std - 1).max() < 0.03 and np.abs(rotvec.mean(0)).max() < 0.02 * std
    assert abs(x.trans.std().item() - 1) < 0.03  # translations untouched
    with pytest.raises(ValueError, match="rotation_noise_std=0"):
        SE3Flow(1, rotation_noise_std=0)


@pytest.mark.parametrize(
    "flow", [SE3Flow(2), EuclideanFlow(2), EuclideanFlow(2, "eef")], ids=["se3", "euclidean", "euclidean-eef"]
)
def test_each_flow_describes_its_own_velocity_and_network_input(flow):
    """What differs between the flows is said by the flow, so the model never branches on its type: the
    translation, rotation and extra parts tile the velocity, and the network input has its declared width."""
    covered = [i for part in flow.velocity_parts.values() for i in range(flow.velocity_dim)[part]]
    assert covered == list(range(flow.velocity_dim))
    assert len(range(flow.velocity_dim)[flow.velocity_parts["extra"]]) == flow.extra_dim == 2
    x = flow.noise(3, 5)
    assert flow.batch_size(x) == 3
    assert flow.network_input(x).shape == (3, 5, flow.network_input_dim)
