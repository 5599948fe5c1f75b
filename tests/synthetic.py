"""A small synthetic token task: the end effector must reach a grasp pose defined in a target object's
frame, ignore a distractor, and close the gripper there.

A test fixture: it needs no simulator, so it trains in minutes on a CPU and has an exact expert; the fast
learning tests and the ``lerobot-train`` command test use it. Tokens follow the project schema:

| token | pose | feature (F = 4) |
|---|---|---|
| 0 end effector | world pose | one-hot 0, gripper opening in metres (0.08 open, 0 closed) |
| 1 target | world pose | one-hot 1, 0 |
| 2 distractor | world pose | one-hot 2, 0 |

Action (10): the next target EEF pose (world) + gripper command (-1 open, +1 close). The expert moves
towards the grasp pose ``T_target * T_grasp`` (5 cm along the target's z axis, gripper pointing down its
z axis) by at most ``max_step`` metres / radians per step, and closes once it is within ``close_radius``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import torch
from torch import Tensor

from lerobot_actionflow import schema
from lerobot_actionflow.core import geometry as g

NUM_TOKENS = 3
FEATURE_DIM = 4
GRIPPER_OPEN_WIDTH = 0.08
GRASP_OFFSET = (0.0, 0.0, 0.05)


@dataclass
class Scene:
    """World poses ``[B, 3, 3]`` / ``[B, 3]`` of the EEF, the target and the distractor."""

    eef_rot: Tensor
    eef_trans: Tensor
    target_rot: Tensor
    target_trans: Tensor
    distractor_rot: Tensor
    distractor_trans: Tensor

    def with_eef(self, rot: Tensor, trans: Tensor) -> Scene:
        """The same objects with the end effector at ``(rot, trans)``."""
        return dataclasses.replace(self, eef_rot=rot, eef_trans=trans)

    def transformed(self, rot: Tensor, trans: Tensor) -> Scene:
        """The same scene moved rigidly by the world transform ``(rot [3, 3], trans [3])``."""
        fields = {}
        for name in ("eef", "target", "distractor"):
            r, p = g.compose(rot, trans, getattr(self, f"{name}_rot"), getattr(self, f"{name}_trans"))
            fields[f"{name}_rot"], fields[f"{name}_trans"] = r, p
        return Scene(**fields)


def _yaw_tilt(batch: int, gen: torch.Generator, max_tilt: float) -> Tensor:
    """Rotations with uniform yaw and a tilt of at most ``max_tilt`` about a random horizontal axis."""
    yaw = torch.rand(batch, generator=gen, dtype=torch.float64) * 2 * math.pi
    axis_angle = torch.rand(batch, generator=gen, dtype=torch.float64) * 2 * math.pi
    tilt = (torch.rand(batch, generator=gen, dtype=torch.float64) * 2 - 1) * max_tilt
    zero = torch.zeros_like(yaw)
    r_yaw = g.so3_exp(torch.stack([zero, zero, yaw], -1))
    r_tilt = g.so3_exp(torch.stack([tilt * axis_angle.cos(), tilt * axis_angle.sin(), zero], -1))
    return r_tilt @ r_yaw


def sample_scenes(batch: int, seed: int) -> Scene:
    """Random scenes: EEF 0.2-0.3 m above a table, objects within +-0.15 m of the point below it."""
    gen = torch.Generator().manual_seed(seed)
    f64 = torch.float64

    def uniform(lo: float, hi: float, *shape: int) -> Tensor:
        return lo + (hi - lo) * torch.rand(*shape, generator=gen, dtype=f64)

    flip = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=f64))  # gripper z axis pointing down
    eef_rot = _yaw_tilt(batch, gen, 0.3) @ flip
    eef_trans = torch.stack(
        [uniform(0.3, 0.6, batch), uniform(-0.2, 0.2, batch), uniform(0.2, 0.3, batch)], -1
    )
    below = eef_trans * torch.tensor([1.0, 1.0, 0.0], dtype=f64)
    objects = []
    for _ in range(2):
        offset = torch.cat([uniform(-0.15, 0.15, batch, 2), torch.full((batch, 1), 0.02, dtype=f64)], -1)
        objects += [_yaw_tilt(batch, gen, 0.0), below + offset]
    return Scene(eef_rot, eef_trans, *objects)


def grasp_pose(scene: Scene) -> tuple[Tensor, Tensor]:
    """The pose the expert reaches: above the target along its z axis, gripper z pointing down."""
    f64 = scene.target_rot.dtype
    flip = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=f64))
    offset = torch.tensor(GRASP_OFFSET, dtype=f64).expand_as(scene.target_trans)
    return g.compose(scene.target_rot, scene.target_trans, flip.expand_as(scene.target_rot), offset)


def expert_step(
    eef_rot: Tensor,
    eef_trans: Tensor,
    goal_rot: Tensor,
    goal_trans: Tensor,
    max_step: float = 0.02,
    close_radius: float = 0.005,
) -> tuple[Tensor, Tensor, Tensor]:
    """Next commanded pose (at most ``max_step`` m and ``5 max_step`` rad closer to the goal) and gripper."""
    delta = goal_trans - eef_trans
    dist = delta.norm(dim=-1, keepdim=True)
    trans = eef_trans + delta * (max_step / dist.clamp_min(max_step)).clamp(max=1.0)
    omega = g.so3_log(eef_rot.transpose(-1, -2) @ goal_rot)
    angle = omega.norm(dim=-1, keepdim=True)
    rot = eef_rot @ g.so3_exp(omega * (5 * max_step / angle.clamp_min(5 * max_step)).clamp(max=1.0))
    gripper = torch.where(dist[..., 0] < close_radius, 1.0, -1.0).to(eef_trans.dtype)
    return rot, trans, gripper


def gripper_width(command: Tensor) -> Tensor:
    """Opening (m) after a gripper command: closed for a positive command, fully open otherwise."""
    return torch.where(command > 0, 0.0, GRIPPER_OPEN_WIDTH).to(command.dtype)


def state_vector(poses: Tensor, feats: Tensor) -> Tensor:
    """``observation.state`` ``[*, 10]``: the EEF pose (token 0) and the gripper opening."""
    return torch.cat([poses[..., 0, :], feats[..., 0, 3:4]], -1)


def observe(scene: Scene, width: Tensor) -> tuple[Tensor, Tensor]:
    """Token poses ``[B, 3, 9]`` and features ``[B, 3, 4]`` (float32) of a scene."""
    poses = torch.stack(
        [
            g.rt_to_pose9(scene.eef_rot, scene.eef_trans),
            g.rt_to_pose9(scene.target_rot, scene.target_trans),
            g.rt_to_pose9(scene.distractor_rot, scene.distractor_trans),
        ],
        dim=1,
    )
    feats = torch.zeros(poses.shape[0], NUM_TOKENS, FEATURE_DIM, dtype=poses.dtype)
    feats[:, :, :NUM_TOKENS] = torch.eye(NUM_TOKENS, dtype=poses.dtype)
    feats[:, 0, 3] = width
    return poses.float(), feats.float()


def rollout_expert(scene: Scene, steps: int) -> dict[str, Tensor]:
    """Run the expert for ``steps`` steps: token poses ``[B, S, 3, 9]``, features ``[B, S, 3, 4]``,
    actions ``[B, S, 10]`` (the EEF reaches each commanded pose exactly: kinematic simulation)."""
    goal_rot, goal_trans = grasp_pose(scene)
    eef_rot, eef_trans = scene.eef_rot, scene.eef_trans
    width = torch.full(eef_trans.shape[:1], GRIPPER_OPEN_WIDTH, dtype=eef_trans.dtype)
    out = {"token_poses": [], "token_features": [], "action": []}
    for _ in range(steps):
        poses, feats = observe(scene.with_eef(eef_rot, eef_trans), width)
        rot, trans, gripper = expert_step(eef_rot, eef_trans, goal_rot, goal_trans)
        out["token_poses"].append(poses)
        out["token_features"].append(feats)
        out["action"].append(torch.cat([g.rt_to_pose9(rot, trans), gripper[:, None]], -1).float())
        eef_rot, eef_trans = rot, trans
        width = gripper_width(gripper)
    return {k: torch.stack(v, dim=1) for k, v in out.items()}


def training_windows(rollout: dict[str, Tensor], n_obs_steps: int, horizon: int) -> dict[str, Tensor]:
    """Cut rollouts into training samples the way LeRobot's delta indices do: ``n_obs_steps`` of history
    (clamped at the episode start) and ``horizon`` future actions (clamped at the end, flagged in
    ``action_is_pad``). Returns keys ``observation.token_poses [M, T, N, 9]``,
    ``observation.token_features [M, T, N, F]``, ``action [M, H, 10]``, ``action_is_pad [M, H]``."""
    b, steps = rollout["action"].shape[:2]
    frames = torch.arange(steps)
    obs_idx = (frames[:, None] + torch.arange(1 - n_obs_steps, 1)).clamp(0, steps - 1)  # [S, T]
    act_raw = frames[:, None] + torch.arange(horizon)  # [S, H]
    act_idx = act_raw.clamp(max=steps - 1)
    return {
        schema.TOKEN_POSES: rollout["token_poses"][:, obs_idx].flatten(0, 1),
        schema.TOKEN_FEATURES: rollout["token_features"][:, obs_idx].flatten(0, 1),
        schema.ACTION: rollout["action"][:, act_idx].flatten(0, 1),
        "action_is_pad": (act_raw > steps - 1).expand(b, -1, -1).flatten(0, 1),
    }


TASK_STRING = "reach the grasp pose above the target object and close the gripper"


def dataset_features() -> dict[str, dict]:
    """LeRobotDataset feature spec of the synthetic task, following the project's token schema."""
    return schema.dataset_features(schema.token_shapes(NUM_TOKENS, FEATURE_DIM))


def write_dataset(root, repo_id: str, episodes: int, steps: int = 30, seed: int = 0, fps: int = 20):
    """Record ``episodes`` expert episodes of ``steps`` frames into a new LeRobotDataset at ``root``.

    Returns the dataset. ``root`` must not exist yet (LeRobot refuses to overwrite a dataset).
    """
    import datasets
    from lerobot.datasets.lerobot_dataset import LeRobotDataset
    from tqdm import tqdm

    rollout = rollout_expert(sample_scenes(episodes, seed), steps)
    ds = LeRobotDataset.create(
        repo_id=repo_id, fps=fps, features=dataset_features(), root=root, use_videos=False
    )
    datasets.disable_progress_bars()  # one bar per episode otherwise; ours below counts episodes
    for ep in tqdm(range(episodes), desc="recording episodes", unit="ep", disable=episodes < 5):
        for i in range(steps):
            poses = rollout["token_poses"][ep, i]
            feats = rollout["token_features"][ep, i]
            obs = {
                "token_poses": poses.numpy(),
                "token_features": feats.numpy(),
                "agent_pos": state_vector(poses, feats).numpy(),
                "environment_state": poses[1:].flatten().numpy(),
            }
            ds.add_frame(schema.dataset_frame(obs, rollout["action"][ep, i].numpy(), TASK_STRING))
        ds.save_episode()
    ds.finalize()
    return ds


@dataclass
class EvalResult:
    success: Tensor  # [B] bool: within the tolerances with the gripper closed at the end
    trans_error: Tensor  # [B] m, final EEF to grasp pose
    rot_error: Tensor  # [B] rad


@torch.no_grad()
def evaluate_closed_loop(
    select_action, scene: Scene, steps: int = 40, trans_tol: float = 0.01, rot_tol: float = 0.05
) -> EvalResult:
    """Roll a policy out in the kinematic synthetic scene (the EEF reaches each commanded pose exactly).

    ``select_action`` maps an observation dict (``observation.token_poses [B, 3, 9]``,
    ``observation.token_features [B, 3, 4]``, ``observation.state [B, 10]``) to actions ``[B, 10]``.
    """
    goal_rot, goal_trans = grasp_pose(scene)
    eef_rot, eef_trans = scene.eef_rot, scene.eef_trans
    width = torch.full(eef_trans.shape[:1], GRIPPER_OPEN_WIDTH, dtype=eef_trans.dtype)
    gripper = -torch.ones_like(width)
    for _ in range(steps):
        poses, feats = observe(scene.with_eef(eef_rot, eef_trans), width)
        obs = {
            schema.TOKEN_POSES: poses,
            schema.TOKEN_FEATURES: feats,
            schema.STATE: state_vector(poses, feats),
        }
        action = select_action(obs).to(torch.float64)
        eef_rot, eef_trans = g.pose9_to_rt(action[:, :9])
        gripper = action[:, 9]
        width = gripper_width(gripper)
    trans_err = (eef_trans - goal_trans).norm(dim=-1)
    rot_err = g.geodesic_distance(eef_rot, goal_rot)
    success = (trans_err < trans_tol) & (rot_err < rot_tol) & (gripper > 0)
    return EvalResult(success, trans_err, rot_err)
