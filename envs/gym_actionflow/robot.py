"""Franka Panda arm + parallel gripper, built into an ``mujoco.MjSpec`` scene, and its pose controller.

The link meshes come from the Franka assets inside the installed ``gymnasium-robotics`` wheel (Apache-2.0); we
never download anything. The kinematic chain, collision geometry of the fingers, actuators and gains are ours:
position servos with gravity compensation, finger pads as boxes (stable grasps), and a tool-centre point (TCP)
site between the finger pads.

The controller turns an absolute TCP pose target into joint targets with damped-least-squares IK
(``PoseController.solve``), so the policy's action space is the TCP pose in the world frame.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from gym_actionflow.geometry import rotation_log

ARM_JOINTS = tuple(f"panda_joint{i}" for i in range(1, 8))
FINGER_JOINTS = ("panda_finger_left", "panda_finger_right")
TCP_SITE = "tcp"
WRIST_CAMERA = "wrist"
MAX_FINGER = 0.04
"""Each finger slides 0..4 cm, so the opening between the pads is 0..8 cm."""
MAX_IK_STEP = 0.5
"""Largest joint-space step (rad, Euclidean norm) of one IK iteration."""
TCP_OFFSET = 0.1654 + 0.070
"""Distance from the flange frame (link 7) to the TCP, along its z axis: the middle of the finger pads."""

# Link frames of the Franka chain used by the shipped meshes: (name, pos, euler xyz, joint range).
_CHAIN = (
    ("link1", (0, 0, 0.333), (0, 0, 0), (-2.8973, 2.8973)),
    ("link2", (0, 0, 0), (-np.pi / 2, 0, 0), (-1.7628, 1.7628)),
    ("link3", (0, -0.316, 0), (np.pi / 2, 0, 0), (-2.8973, 2.8973)),
    ("link4", (0.0825, 0, 0), (np.pi / 2, 0, 0), (-3.0718, -0.4)),
    ("link5", (-0.0825, 0.384, 0), (-np.pi / 2, 0, 0), (-2.8973, 2.8973)),
    ("link6", (0, 0, 0), (1.57, 0, 1.57), (-1.6573, 2.1127)),
    ("link7", (0.088, 0, 0), (1.57, 0, 0.7854), (-2.8973, 2.8973)),
)
_MASSES = (2.7063, 2.73046, 2.04104, 2.08129, 3.00049, 1.3235, 0.2)
_KP = (4500.0, 4500.0, 3500.0, 3500.0, 2000.0, 2000.0, 1000.0)
_FORCE = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)
"""Joint torque limits (N m) of the Panda's datasheet: the servos never push harder than the real arm can."""
FINGER_FORCE = 70.0
FINGER_KP = FINGER_FORCE / 0.01
"""Each finger servo pushes with at most the Panda hand's continuous grasp force (70 N), and reaches it once
the finger is held 1 cm short of its target: a closed hand grips anything wider than 2 cm with 70 N, like the
real hand's force-controlled grasp. (A softer servo gripped a 4 cm cube with 6 N.) Critically damped, it still
closes at about 0.5 m/s."""


def franka_mesh_dir() -> Path:
    """Directory of the Franka STL meshes inside the installed gymnasium-robotics wheel."""
    spec = importlib.util.find_spec("gymnasium_robotics")
    if spec is None or not spec.submodule_search_locations:
        raise ImportError(
            "gym_actionflow needs the Franka meshes shipped in the 'gymnasium-robotics' wheel; "
            "install it with `pip install gymnasium-robotics==1.4.2`"
        )
    root = Path(spec.submodule_search_locations[0])
    mesh_dir = root / "envs" / "assets" / "kitchen_franka" / "franka_assets" / "meshes"
    if not (mesh_dir / "visual" / "link0.stl").is_file():
        raise FileNotFoundError(f"Franka meshes not found under {mesh_dir}; reinstall gymnasium-robotics")
    return mesh_dir


def _euler_quat(euler: tuple[float, float, float]) -> np.ndarray:
    q = np.empty(4)
    mujoco.mju_euler2Quat(q, np.asarray(euler, dtype=np.float64), "xyz")
    return q


def add_panda(spec: mujoco.MjSpec, base_pos: tuple[float, float, float]) -> None:
    """Add the arm, gripper, TCP site, wrist camera and actuators to ``spec``.

    Arm joints are position servos (critically damped, gravity compensated bodies), so the commanded joint
    targets from IK are held to well under a millimetre at the TCP. Each finger has its own position servo.
    """
    mesh_dir = franka_mesh_dir()
    names = ["link0", *(c[0] for c in _CHAIN), "hand", "finger"]
    for name in names:
        spec.add_mesh(name=f"panda_{name}", file=str(mesh_dir / "visual" / f"{name}.stl"))
    spec.add_material(name="panda_white", rgba=(0.93, 0.93, 0.93, 1.0))
    spec.add_material(name="panda_dark", rgba=(0.25, 0.25, 0.27, 1.0))

    def visual(body: mujoco.MjsBody, mesh: str, **kwargs) -> None:
        body.add_geom(
            type=mujoco.mjtGeom.mjGEOM_MESH,
            meshname=mesh,
            contype=0,
            conaffinity=0,
            group=2,
            density=0,
            material=kwargs.pop("material", "panda_white"),
            **kwargs,
        )

    def collision(body: mujoco.MjsBody, geom_type: mujoco.mjtGeom, **kwargs) -> None:
        """A massless collision geom of the robot (contype 2: the robot does not collide with itself)."""
        body.add_geom(type=geom_type, contype=2, conaffinity=1, group=3, density=0, **kwargs)

    base = spec.worldbody.add_body(name="panda_link0", pos=base_pos)
    visual(base, "panda_link0")
    parent = base
    for i, ((name, pos, euler, rng), mass) in enumerate(zip(_CHAIN, _MASSES, strict=True)):
        body = parent.add_body(name=f"panda_{name}", pos=pos, quat=_euler_quat(euler), gravcomp=1.0)
        body.add_joint(
            name=ARM_JOINTS[i],
            type=mujoco.mjtJoint.mjJNT_HINGE,
            axis=(0, 0, 1),
            range=rng,
            limited=mujoco.mjtLimited.mjLIMITED_TRUE,
            damping=1.0,
            armature=0.1,
        )
        visual(body, f"panda_{name}")
        body.mass = mass
        body.inertia = (0.02, 0.02, 0.02)
        body.explicitinertial = True
        parent = body

    link7 = parent
    # Coarse collision volumes for the forearm, wrist and hand, so the arm cannot sweep through the scene.
    collision(link7, mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=(0, 0, 0.06, 0, 0, 0.11), size=(0.05, 0, 0))
    hand_quat = _euler_quat((0, 0, -np.pi / 4))
    hand = link7.add_body(name="panda_hand", pos=(0, 0, 0.107), quat=hand_quat, gravcomp=1.0)
    hand.mass, hand.inertia, hand.explicitinertial = 0.81909, (0.003, 0.003, 0.002), True
    visual(hand, "panda_hand")
    collision(hand, mujoco.mjtGeom.mjGEOM_BOX, pos=(0, 0, 0.025), size=(0.03, 0.1, 0.03))
    hand.add_site(
        name=TCP_SITE, pos=(0, 0, TCP_OFFSET - 0.107), size=(0.004, 0, 0), group=4, rgba=(1, 0, 0, 1)
    )
    hand.add_camera(
        name=WRIST_CAMERA,
        pos=(0.06, 0, 0.03),
        quat=_euler_quat((0, np.pi, np.pi / 2 + 0.0)),
        fovy=75.0,
    )
    # The camera looks along the TCP's +z (down towards the fingers), mounted on the hand's side.
    for side, joint in zip((1.0, -1.0), FINGER_JOINTS, strict=True):
        finger = hand.add_body(name=f"{joint}_body", pos=(0, 0, 0.0584), gravcomp=1.0)
        finger.mass, finger.inertia, finger.explicitinertial = 0.05, (1e-5, 1e-5, 1e-5), True
        finger.add_joint(
            name=joint,
            type=mujoco.mjtJoint.mjJNT_SLIDE,
            axis=(0, side, 0),
            range=(0, MAX_FINGER),
            limited=mujoco.mjtLimited.mjLIMITED_TRUE,
            damping=5.0,
            armature=0.5,
        )
        visual(finger, "panda_finger", quat=(1, 0, 0, 0) if side > 0 else (0, 0, 0, 1), material="panda_dark")
        # Pad: inner face at y = 0 of the finger frame (fingers touch when both joints are 0).
        collision(
            finger,
            mujoco.mjtGeom.mjGEOM_BOX,
            name=f"{joint}_pad",
            pos=(0, side * 0.006, 0.07),
            size=(0.009, 0.006, 0.018),
            friction=(1.5, 0.02, 0.001),
            condim=4,
            solref=(0.004, 1.0),
            solimp=(0.95, 0.99, 0.001, 0.5, 2),
        )
        collision(finger, mujoco.mjtGeom.mjGEOM_BOX, pos=(0, side * 0.012, 0.035), size=(0.009, 0.008, 0.02))

    for joint, kp, force in zip(ARM_JOINTS, _KP, _FORCE, strict=True):
        act = spec.add_actuator(name=joint, target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_position(kp=kp, dampratio=1.0)
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = (-force, force)
        act.inheritrange = 1.0
    for joint in FINGER_JOINTS:
        act = spec.add_actuator(name=joint, target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_position(kp=FINGER_KP, dampratio=1.0)
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = (-FINGER_FORCE, FINGER_FORCE)
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.ctrlrange = (0.0, MAX_FINGER)


@dataclass
class RobotRefs:
    """Indices into a compiled model for the arm and gripper."""

    qpos: np.ndarray  # (7,) qpos addresses of the arm joints
    dof: np.ndarray  # (7,) dof addresses of the arm joints
    finger_qpos: np.ndarray  # (2,)
    arm_ctrl: np.ndarray  # (7,) actuator ids
    finger_ctrl: np.ndarray  # (2,)
    tcp: int  # site id
    lower: np.ndarray  # (7,) joint limits
    upper: np.ndarray
    pad_geoms: tuple[int, int]

    @classmethod
    def from_model(cls, model: mujoco.MjModel) -> RobotRefs:
        jid = [model.joint(n).id for n in ARM_JOINTS]
        fid = [model.joint(n).id for n in FINGER_JOINTS]
        return cls(
            qpos=model.jnt_qposadr[jid].copy(),
            dof=model.jnt_dofadr[jid].copy(),
            finger_qpos=model.jnt_qposadr[fid].copy(),
            arm_ctrl=np.array([model.actuator(n).id for n in ARM_JOINTS]),
            finger_ctrl=np.array([model.actuator(n).id for n in FINGER_JOINTS]),
            tcp=model.site(TCP_SITE).id,
            lower=model.jnt_range[jid, 0].copy(),
            upper=model.jnt_range[jid, 1].copy(),
            pad_geoms=(model.geom(f"{FINGER_JOINTS[0]}_pad").id, model.geom(f"{FINGER_JOINTS[1]}_pad").id),
        )


class PoseController:
    """Damped-least-squares IK from an absolute TCP pose to arm joint targets.

    It iterates on a private ``MjData`` (the simulation state is never touched), starting from the previous
    solution so consecutive targets give consecutive joint solutions, clips to joint limits, and pulls the
    redundant (null-space) motion gently towards a rest posture so the elbow does not drift over an episode.
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        refs: RobotRefs,
        damping: float = 1e-4,
        iterations: int = 20,
        tolerance: float = 1e-5,
        rest: np.ndarray | None = None,
    ) -> None:
        self.model = model
        self.refs = refs
        self.scratch = mujoco.MjData(model)
        self.damping = damping
        self.iterations = iterations
        self.tolerance = tolerance
        self.rest = rest
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))

    def tcp_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Forward kinematics: arm joints (7,) -> (TCP position (3,), rotation (3, 3))."""
        d = self.scratch
        d.qpos[self.refs.qpos] = q
        mujoco.mj_kinematics(self.model, d)
        return d.site_xpos[self.refs.tcp].copy(), d.site_xmat[self.refs.tcp].reshape(3, 3).copy()

    def solve(self, q_init: np.ndarray, pos: np.ndarray, rot: np.ndarray) -> np.ndarray:
        """Joint targets (7,) whose TCP pose is (pos, rot), or the closest reachable in the DLS sense.

        Converges to ``tolerance`` metres (and 10x that in radians) in a few iterations when started from the
        previous step's solution. The posture (null-space) pull is applied on the first iteration only, so it
        never fights convergence.
        """
        m, d, r = self.model, self.scratch, self.refs
        q = np.clip(np.asarray(q_init, dtype=np.float64).copy(), r.lower, r.upper)
        best_q, best_cost = q, np.inf
        for it in range(self.iterations):
            d.qpos[r.qpos] = q
            mujoco.mj_kinematics(m, d)
            x = d.site_xpos[r.tcp]
            xr = d.site_xmat[r.tcp].reshape(3, 3)
            err = np.concatenate([pos - x, xr @ rotation_log(xr.T @ rot)])
            cost = err[:3] @ err[:3] + 0.01 * err[3:] @ err[3:]
            if cost < best_cost:
                best_q, best_cost = q, cost
            if (
                it > 0
                and err[:3] @ err[:3] < self.tolerance**2
                and err[3:] @ err[3:] < (10 * self.tolerance) ** 2
            ):
                break
            mujoco.mj_comPos(m, d)
            mujoco.mj_jacSite(m, d, self._jacp, self._jacr, r.tcp)
            jac = np.concatenate([self._jacp[:, r.dof], self._jacr[:, r.dof]])  # (6, 7)
            jjt = jac @ jac.T
            jjt[np.diag_indices(6)] += self.damping
            jjt_inv = np.linalg.inv(jjt)
            dq = jac.T @ (jjt_inv @ err)
            if it == 0 and self.rest is not None:
                null = np.eye(7) - jac.T @ jjt_inv @ jac
                dq += null @ (0.05 * (self.rest - q))
            # Small steps: near singular or unreachable targets a full DLS step can jump between IK branches.
            dq *= min(1.0, MAX_IK_STEP / (np.linalg.norm(dq) + 1e-12))
            q = np.clip(q + dq, r.lower, r.upper)
        # Unreachable targets: keep the closest pose found rather than wherever the last iterate landed.
        return best_q
