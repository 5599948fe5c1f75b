"""Mug Hanging (ActionFlow's equivariance experiment): pick up a mug and hang it by its handle on a hanger."""

from __future__ import annotations

import time
import warnings

import mujoco
import numpy as np
from gymnasium import spaces

from gym_actionflow.base import POSITION_BOUND, TABLE_TOP, ManipulationEnv
from gym_actionflow.geometry import yaw_quat
from gym_actionflow.placement import Region
from gym_actionflow.point_cloud import (
    back_project,
    farthest_point_sample,
    in_boxes,
    look_at_xyaxes,
    voxel_unique,
)
from gym_actionflow.registry import check_choice
from gym_actionflow.robot import WRIST_CAMERA

# ---------------------------------------------------------------- mug (free body), mug frame
# Mug frame: origin at the centre of the mug's bottom (on the table when it stands), z up along the mug's
# axis, +x pointing at the handle, y along the axis of the handle's opening.
MUG_RADIUS = 0.032
"""Outer radius of the mug's body (m): 6.4 cm across, so the open gripper (8 cm) closes around it."""
MUG_WALL = 0.004
MUG_HEIGHT = 0.085
MUG_WALLS = 16
"""The body is an open shell of ``MUG_WALLS`` flat 4 mm boxes whose outer faces are tangent to the outer
radius, 8.5 cm tall, on a 6 mm bottom disk."""
MUG_BOTTOM = 0.006
HANDLE_GAP = 0.024
HOLE_LOW, HOLE_HIGH = 0.020, 0.066
"""The handle's opening: 2.4 cm wide (from the mug wall outwards, along x) and 4.6 cm tall (mug-frame z from
2 cm to 6.6 cm), enough for the 1.2 cm peg tilted by 30 degrees with 6 mm to spare on each side."""
HANDLE_BAR = 0.008
HANDLE_HALF_Y = 0.007
"""The handle's three bars (upper and lower arms, outer upright) are 8 mm thick boxes, 1.4 cm deep (y)."""
HOLE_CENTER = np.array([MUG_RADIUS + HANDLE_GAP / 2, 0.0, (HOLE_LOW + HOLE_HIGH) / 2])
"""Centre of the handle's opening in the mug frame."""
MUG_FOOTPRINT = MUG_RADIUS + HANDLE_GAP + HANDLE_BAR
"""Radius (m) of the disc around the mug's axis that covers the whole mug, handle included (6.4 cm)."""
MUG_DENSITY = 800.0
"""kg/m^3: the mug weighs about 70 g."""

# ---------------------------------------------------------------- hanger (static fixture), hanger frame
# Hanger frame: origin at the foot of the pole on the table, z up, +x the horizontal direction of the peg.
PLATE_RADIUS = 0.055
PLATE_HALF = 0.006
"""Base plate: a disk 11 cm across and 1.2 cm thick."""
POLE_RADIUS = 0.010
PEG_ROOT_Z = 0.19
"""The peg leaves the pole 19 cm above the table; the pole ends 1.5 cm higher."""
POLE_TOP = PEG_ROOT_Z + 0.015
PEG_RADIUS = 0.006
PEG_TILT = np.deg2rad(30.0)
"""The peg points away from the pole, 30 degrees above horizontal, so a hung mug slides towards the pole,
never off."""
PEG_LENGTH = 0.12
"""From the pole axis to the centre of the peg's rounded tip (m): the tip reaches 10.4 cm from the pole axis
and 25 cm above the table."""
PEG_DIRECTION = np.array([np.cos(PEG_TILT), 0.0, np.sin(PEG_TILT)])
"""Unit vector along the peg (root to tip), in the hanger frame."""
PEG_ROOT = np.array([0.0, 0.0, PEG_ROOT_Z])
PEG_TIP = PEG_ROOT + PEG_LENGTH * PEG_DIRECTION

# ---------------------------------------------------------------- layouts
_TEST_REGIONS = (
    Region((0.02, 0.12), (0.18, 0.26), (np.pi - np.pi / 8, np.pi + np.pi / 8)),
    Region((0.02, 0.12), (-0.26, -0.18), (np.pi - np.pi / 8, np.pi + np.pi / 8)),
)
HANGER_REGIONS = {
    "train": (Region((0.14, 0.14), (0.0, 0.0), (np.pi, np.pi)),),
    "test": _TEST_REGIONS,
    "scene_moved": _TEST_REGIONS,
}
"""Where the hanger's pole stands and where its peg points (yaw of the hanger's x axis). ``train``: one fixed
pose, in front of the robot at (0.14, 0) with the peg pointing back at the robot (yaw pi). ``test``: moved to
the left (y in [0.18, 0.26]) or the right (y in [-0.26, -0.18]) side of the table, half the episodes each,
x in [0.02, 0.12], the peg's yaw within 22.5 degrees of pointing back at the robot. ``scene_moved``: the
hanger placed as in ``test``, and the mug moved and turned with it (see ``MugHangingEnv``)."""
TRAIN_HANGER = (np.array([0.14, 0.0]), np.pi)
"""The ``train`` hanger's pole foot (x, y) and peg heading."""
MUG_REGION = Region((-0.20, -0.08), (-0.045, 0.045), (-np.pi, np.pi))
"""The mug stands upright at x in [-0.2, -0.08], y in [-0.045, 0.045], in both layouts: between the robot and
the hanger, clear of every hanger placement box (below). Its yaw is drawn from ``MUG_YAWS``."""
MUG_YAWS = {"any": (-np.pi, np.pi), "slight": (-3 * np.pi / 4 - np.pi / 6, -3 * np.pi / 4 + np.pi / 6)}
"""The mug's yaw (its handle's heading) by the ``mug_yaw`` keyword: ``any`` (uniform), or ``slight``, the
paper's protocol ("the demonstrations only include slight variations of the mug poses"): the handle
within 30 degrees of pointing at the robot's front right (yaw -135 degrees), so that hanging it on the
``train`` peg takes a turn of the hand between 15 and 75 degrees."""

# ---------------------------------------------------------------- point cloud
BOX_MARGIN = 0.01
BOX_FLOOR = 0.005
"""The box filter keeps the points inside the axis-aligned world boxes that cover every hanger placement of
the layout (one box per region: train one, test two), grown by 1 cm, from 5 mm above the table top (which
removes the table) to 1 cm above the peg's tip."""
HOVER_TARGET = np.array([0.07, 0.0, 0.10])
HOVER_VIEWS = (
    ((0.07, 0.0, 0.95), (0.07, 0.0, 0.0)),
    *(
        ((0.07 + 0.5 * np.cos(a), 0.5 * np.sin(a), 0.55), tuple(HOVER_TARGET))
        for a in np.deg2rad((40.0, -40.0, 90.0, -90.0, 140.0, -140.0))
    ),
)
"""The seven depth viewpoints (camera position, point looked at), the robot's initial hovering routine: one
straight down from 95 cm above (0.07, 0), six at 55 cm height on a circle of radius 0.5 m around it (at 40,
90 and 140 degrees either side of +x) looking at (0.07, 0, 0.10). They are world cameras ``hover0..6``, the
same for both layouts, and each sees all the hanger placements."""
HOVER_FOVY = 60.0
HOVER_SIZE = 240
"""Each view is a 240 x 240 depth image with a 60 degree field of view (about 3-4 mm per pixel at the
hanger)."""
VOXEL = 0.004
"""The fused views are thinned to one point per 4 mm voxel before farthest point sampling to ``n_points``."""

SENSE_MARGIN = 0.001
"""Pole and peg report contacts up to 1 mm before they touch (MuJoCo ``margin``), with no force until they do
(``gap`` equal to the margin). With stiff contacts a mug resting on the peg sits within microns of it and
the contact comes and goes between control steps; the margin keeps "the mug touches the peg" steady."""
HANG_STEPS = 20
"""Success needs the mug hanging for 20 consecutive control steps (1 s)."""

MUG_RGBA = (0.2, 0.45, 0.75, 1.0)
HANGER_RGBA = (0.55, 0.38, 0.22, 1.0)
_FRICTION = (1.0, 0.005, 0.0001)


def add_mug(spec: mujoco.MjSpec, name: str = "mug") -> mujoco.MjsBody:
    """The mug: a free body (joint ``name + '_joint'``) in the mug frame described above."""
    box = mujoco.mjtGeom.mjGEOM_BOX
    body = spec.worldbody.add_body(name=name, pos=(-0.15, 0.0, TABLE_TOP))
    body.add_freejoint(name=f"{name}_joint")
    kw = dict(rgba=MUG_RGBA, density=MUG_DENSITY, friction=_FRICTION, condim=4)
    body.add_geom(name=f"{name}_bottom", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                  size=(MUG_RADIUS - MUG_WALL, MUG_BOTTOM / 2, 0), pos=(0, 0, MUG_BOTTOM / 2), **kw)
    half_len = MUG_RADIUS * np.tan(np.pi / MUG_WALLS)
    r = MUG_RADIUS - MUG_WALL / 2
    for i in range(MUG_WALLS):
        a = 2 * np.pi * (i + 0.5) / MUG_WALLS  # no wall segment is centred on the handle's axis
        body.add_geom(name=f"{name}_wall{i}", type=box, size=(MUG_WALL / 2, half_len, MUG_HEIGHT / 2),
                      pos=(r * np.cos(a), r * np.sin(a), MUG_HEIGHT / 2), quat=yaw_quat(a), **kw)
    x0, x1 = MUG_RADIUS - MUG_WALL, MUG_RADIUS + HANDLE_GAP + HANDLE_BAR
    arm_half = (0.5 * (x1 - x0), HANDLE_HALF_Y, HANDLE_BAR / 2)
    body.add_geom(name=f"{name}_handle_top", type=box, size=arm_half,
                  pos=(0.5 * (x0 + x1), 0, HOLE_HIGH + HANDLE_BAR / 2), **kw)
    body.add_geom(name=f"{name}_handle_bottom", type=box, size=arm_half,
                  pos=(0.5 * (x0 + x1), 0, HOLE_LOW - HANDLE_BAR / 2), **kw)
    body.add_geom(name=f"{name}_handle_side", type=box,
                  size=(HANDLE_BAR / 2, HANDLE_HALF_Y, 0.5 * (HOLE_HIGH - HOLE_LOW) + HANDLE_BAR),
                  pos=(x1 - HANDLE_BAR / 2, 0, HOLE_CENTER[2]), **kw)
    return body


def add_hanger(spec: mujoco.MjSpec, name: str = "hanger") -> mujoco.MjsBody:
    """The hanger: a static body in the hanger frame (base plate, vertical pole, tilted capsule peg)."""
    body = spec.worldbody.add_body(name=name, pos=(0.14, 0.0, TABLE_TOP), quat=yaw_quat(np.pi))
    body.add_geom(name=f"{name}_plate", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                  size=(PLATE_RADIUS, PLATE_HALF, 0), pos=(0, 0, PLATE_HALF), rgba=HANGER_RGBA,
                  friction=_FRICTION)
    body.add_geom(name=f"{name}_pole", type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                  size=(POLE_RADIUS, 0.5 * (POLE_TOP - PLATE_HALF), 0),
                  pos=(0, 0, 0.5 * (POLE_TOP + PLATE_HALF)), rgba=HANGER_RGBA, friction=_FRICTION,
                  margin=SENSE_MARGIN, gap=SENSE_MARGIN)
    body.add_geom(name=f"{name}_peg", type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=(PEG_RADIUS, 0, 0),
                  fromto=(*PEG_ROOT, *PEG_TIP), rgba=HANGER_RGBA, friction=(0.5, 0.005, 0.0001),
                  margin=SENSE_MARGIN, gap=SENSE_MARGIN)
    return body


def hanger_box(region: Region) -> np.ndarray:
    """(2, 3) [low, high] world corners of a box that holds the hanger wherever ``region`` places it."""
    yaws = np.linspace(region.yaw[0], region.yaw[1], 91)
    reach = PEG_TIP[0]
    tip = reach * np.stack([np.cos(yaws), np.sin(yaws)], axis=1)
    low = np.minimum(tip.min(0) - PEG_RADIUS, -PLATE_RADIUS) + [region.x[0], region.y[0]] - BOX_MARGIN
    high = np.maximum(tip.max(0) + PEG_RADIUS, PLATE_RADIUS) + [region.x[1], region.y[1]] + BOX_MARGIN
    top = TABLE_TOP + PEG_TIP[2] + PEG_RADIUS + BOX_MARGIN
    return np.array([[low[0], low[1], TABLE_TOP + BOX_FLOOR], [high[0], high[1], top]])


LAYOUT_BOXES = {name: np.stack([hanger_box(r) for r in regions]) for name, regions in HANGER_REGIONS.items()}
"""Box filter of each layout (K, 2, 3) of [low, high] corners: train one box x in [0.02, 0.205], y in
[-0.065, 0.065]; test two boxes x in [-0.10, 0.185], |y| in [0.115, 0.325]; z from 5 mm to 0.266 m."""


class MugHangingEnv(ManipulationEnv):
    """Mug hanging: pick up the mug and hang it by its handle on the hanger's tilted peg.

    ActionFlow's equivariance experiment (real robot), rebuilt in MuJoCo with primitive shapes. The mug is a
    free open cylinder (6.4 cm across, 8.5 cm tall, 16 wall segments on a bottom disk) with a handle loop on
    one side whose opening is 2.4 x 4.6 cm. The hanger is a static fixture: an 11 cm base plate, a 2 cm pole
    and a capsule peg (1.2 cm thick) leaving the pole 19 cm above the table, 30 degrees above horizontal,
    whose tip reaches 10.4 cm out and 25 cm up. Training data has the hanger always at one pose
    (`variant="train"`); `variant="test"` moves it to either side of the table, which an SE(3)-equivariant
    policy should handle without new data.

    ## Observation
    | key | shape | content |
    |---|---|---|
    | `token_poses` | (3, 9) | world poses: 0 = EEF (TCP), 1 = mug, 2 = hanger |
    | `token_features` | (3, 4) | one-hot token id (3) + gripper opening in m (EEF row only) |
    | `agent_pos` | (10,) | EEF pose (9) + gripper opening |
    | `environment_state` | (18,) | poses of the mug and the hanger token |
    | `point_cloud` | (P, 3) float32 | only with `hanger_obs="point_cloud"`: world points on the hanger |
    | `pixels` | {"wrist": (80, 80, 3) uint8} | only with `obs_mode="pixels"` (see `mask_after_grasp`) |

    Pose vectors are `[x, y, z, r00, r10, r20, r01, r11, r21]` (position + first two rotation columns). Mug
    pose: origin at the centre of its bottom, z along its axis, x pointing at the handle (the handle's opening
    runs along y). Hanger token with `hanger_obs="pose"` (default; the motion-capture variant): the hanger's
    simulator pose, origin at the foot of the pole on the table, x the horizontal direction of the peg, z up.
    With `hanger_obs="point_cloud"` the hanger is seen instead through depth from seven fixed viewpoints
    above and around the placement area (the robot's initial hovering routine; world cameras `hover0..6`),
    rendered once per reset (240 x 240 each), back-projected to world points, box-filtered (the boxes covering
    every hanger placement of the layout, 5 mm above the table up to 1 cm above the peg tip: table, robot and
    mug are outside), fused, thinned to one point per 4 mm voxel and reduced to `n_points` (P, default 512)
    by farthest point sampling from a start drawn from the env's `np_random`. The hanger token is then the
    cloud's centroid with the identity rotation, and `point_cloud` carries the points (constant within an
    episode: the hanger never moves). Boxes: train x in [0.02, 0.205], y in [-0.065, 0.065]; test x in
    [-0.10, 0.185], |y| in [0.115, 0.325]. The points lie within 0.4 mm of the hanger's surfaces; the cloud
    costs about 0.2 s per reset (`cloud_seconds`), the renderer is kept across resets and freed by `close()`.

    `mask_after_grasp=True` (default False; needs `obs_mode="pixels"`) removes the wrist image's background
    while the mug is held, after the paper's modified image observations: every pixel that does not show the
    mug, the gripper's fingers included, is set to black (0, 0, 0); the mug's pixels keep their colour. "Held"
    is `mug_held()`: both finger pads touch the mug (the base's `is_grasped`), checked on the state the image
    shows, so the mask comes with the grasp and goes when the gripper lets go. The paper's trigger, the closed
    gripper, differs mainly when the gripper closes on nothing: here the image then stays unmasked, so a
    missed grasp stays visible. Which pixels show the mug comes from MuJoCo's segmentation rendering of the
    same camera (a second cached renderer, about 7 ms per held step). The paper, on the real robot, kept a
    fixed 30 x 30 pixel centre region of the image once the gripper closed and noted that masking by depth
    would do the same; this camera sees the held mug at the bottom of the image, not in its centre, so the
    mask follows the mug's own pixels instead (the exact version of that masking). Before the grasp the image
    is the unmasked one, bit for bit.

    ## Action
    (10,) float32: absolute target TCP pose (9, world frame) + gripper command in [-1 open, 1 close]. The
    rotation is orthonormalised, the position clipped to the workspace and each step rate-limited to
    3 cm / 0.3 rad.

    ## Success
    The mug hangs by its handle: the peg's axis passes through the handle's opening, the mug touches the peg
    (or the pole) and touches neither the table, the hanger's base plate nor any part of the robot (so it is
    not held), and all this has held for at least 20 consecutive control steps (1 s). The count advances in
    `step` after the physics (reset clears it); `is_success()` only reads it.

    ## Starting state
    The arm at its home pose, gripper open. The mug stands upright at x in [-0.2, -0.08], y in
    [-0.045, 0.045]; its yaw by `mug_yaw`: `"any"` (default, uniform) or `"slight"` (the paper's protocol,
    "slight variations of the mug poses": the handle within 30 degrees of yaw -135 degrees, so that the hand
    turns 15-75 degrees to hang it on the `train` peg). `variant="train"`: the hanger's pole at (0.14, 0), the
    peg pointing back at the robot (yaw pi). `variant="test"`: the pole at x in [0.02, 0.12] and y in
    [0.18, 0.26] (left) or [-0.26, -0.18] (right), equally likely, with yaw in [pi - pi/8, pi + pi/8]; the mug
    stays where it was, so it now stands 9-30 cm to the side of the peg's line, a relative layout no
    `train` episode has. `variant="scene_moved"`: the hanger placed as in `test` and the mug moved and turned
    with it, so the relative layout is `train`'s up to one rigid motion (the generalisation an SE(3)-
    equivariant policy guarantees, apart from where the arm starts).

    ## Episode end
    Terminates on success (unless `terminate_on_success=False`); truncated after `max_episode_steps` (400).

    ## Version history
    * v0: initial release; the hanger placement is the `variant` keyword of every task (`layout=`, its first
      name, still works with a DeprecationWarning). Added since, defaults unchanged: `mug_yaw` and
      `variant="scene_moved"`. With the stiff contacts of the Panda-like physics, the peg and pole sense
      the mug 1 mm early (`SENSE_MARGIN`, no force), so a mug resting on the peg counts as hanging at every
      step instead of flickering in and out of contact (which could only delay or deny success). Added since,
      default unchanged: `mask_after_grasp`.
    """

    entity_names = ("mug", "hanger")
    variants = ("train", "test", "scene_moved")
    task_description = "Pick up the mug and hang it by its handle on the hanger's peg."
    default_image_size = 80

    def __init__(self, variant: str | None = None, hanger_obs: str = "pose", n_points: int = 512,
                 layout: str | None = None, mug_yaw: str = "any", mask_after_grasp: bool = False,
                 **kwargs) -> None:
        if layout is not None:
            warnings.warn("MugHangingEnv(layout=...) is deprecated: use variant=... (the same values), "
                          "the keyword of every gym_actionflow task", DeprecationWarning,
                          stacklevel=2)
            check_choice("layout", layout, self.variants, " (where the hanger stands)")
            if variant is not None and variant != layout:
                raise ValueError(f"variant={variant!r} and layout={layout!r} disagree; give variant only")
            variant = layout
        if hanger_obs not in ("pose", "point_cloud"):
            raise ValueError(f"hanger_obs={hanger_obs!r}; expected 'pose' (simulator pose of the hanger) or "
                             "'point_cloud' (depth from the hovering views)")
        if isinstance(n_points, bool) or not isinstance(n_points, int | np.integer) or n_points < 1:
            raise ValueError(
                f"n_points={n_points!r}; expected a positive integer (points in the hanger cloud)"
            )
        check_choice("mug_yaw", mug_yaw, tuple(MUG_YAWS), " (the mug's yaw range)")
        if not isinstance(mask_after_grasp, bool | np.bool_):
            raise ValueError(
                f"mask_after_grasp={mask_after_grasp!r}; expected True (black out the wrist image but the "
                "mug while it is held) or False"
            )
        self.mask_after_grasp = bool(mask_after_grasp)
        self.mug_yaw = mug_yaw
        self.mug_region = Region(MUG_REGION.x, MUG_REGION.y, MUG_YAWS[mug_yaw])
        """Where and at which yaw the mug stands (in ``train``'s frame of the hanger for ``scene_moved``)."""
        self.hanger_obs = hanger_obs
        self.n_points = int(n_points)
        self._cloud = np.zeros((self.n_points, 3), dtype=np.float32)
        self._hang_steps = 0
        self.cloud_seconds = 0.0
        """Wall time (s) the last reset spent rendering and processing the point cloud."""
        super().__init__(variant=variant, **kwargs)
        if self.mask_after_grasp and self.obs_mode != "pixels":
            raise ValueError(
                f"mask_after_grasp=True with obs_mode={self.obs_mode!r}: the mask applies to the wrist "
                "image; pass obs_mode='pixels' (or mask_after_grasp=False)"
            )
        if self.mask_after_grasp and "wrist" not in self.cameras:
            raise ValueError(
                f"mask_after_grasp=True with cameras={self.cameras!r}: the mask applies to the wrist image; "
                "add 'wrist' to cameras (or mask_after_grasp=False)"
            )

    @property
    def layout(self) -> str:
        """The variant (``train`` / ``test``): where the hanger stands. Kept for code written before
        ``variant`` was MugHanging's keyword."""
        return self.variant

    @property
    def boxes(self) -> np.ndarray:
        """The point-cloud box filter of the variant's hanger placements (K, 2, 3)."""
        return LAYOUT_BOXES[self.variant]

    # ------------------------------------------------------------------ scene
    def _build_task(self, spec: mujoco.MjSpec) -> None:
        add_mug(spec)
        add_hanger(spec)
        for i, (pos, target) in enumerate(HOVER_VIEWS):
            spec.worldbody.add_camera(name=f"hover{i}", pos=pos, xyaxes=look_at_xyaxes(pos, target),
                                      fovy=HOVER_FOVY)

    def _cache_refs(self) -> None:
        m = self.model
        self.mug_id = m.body("mug").id
        self.hanger_id = m.body("hanger").id
        self.mug_geoms = self.geoms_of("mug")
        self.mug_geom_ids = np.array(sorted(self.mug_geoms), dtype=np.int32)
        self.hanger_geoms = self.geoms_of("hanger")
        self.support_geoms = {m.geom("hanger_peg").id, m.geom("hanger_pole").id}
        self.ground_geoms = {m.geom("table").id, m.geom("floor").id, m.geom("hanger_plate").id}
        self.robot_geoms = self.geoms_of("panda_link0")
        self.hover_cams = [m.camera(f"hover{i}").id for i in range(len(HOVER_VIEWS))]

    def _sample_layout(self, rng: np.random.Generator) -> None:
        regions = HANGER_REGIONS[self.variant]
        region = regions[int(rng.integers(len(regions)))]
        xy, yaw = region.sample(rng)
        self.place_hanger(xy, yaw)
        mug_xy, mug_yaw = self.mug_region.sample(rng)
        if self.variant == "scene_moved":  # the mug where training puts it relative to the hanger
            turn = yaw - TRAIN_HANGER[1]
            c, s = np.cos(turn), np.sin(turn)
            mug_xy = xy + np.array([[c, -s], [s, c]]) @ (mug_xy - TRAIN_HANGER[0])
            mug_yaw = mug_yaw + turn
        self.set_free_pose("mug_joint", np.array([mug_xy[0], mug_xy[1], TABLE_TOP]), yaw_quat(mug_yaw))
        if self.hanger_obs == "point_cloud":
            mujoco.mj_forward(self.model, self.data)
            start = time.perf_counter()
            self._cloud = self.capture_point_cloud(rng)
            self.cloud_seconds = time.perf_counter() - start

    def place_hanger(self, xy, yaw: float) -> None:
        """Move the (static) hanger's pole foot to ``xy`` with its peg at heading ``yaw``; call mj_forward (or
        reset) afterwards."""
        self.model.body_pos[self.hanger_id] = (xy[0], xy[1], TABLE_TOP)
        self.model.body_quat[self.hanger_id] = yaw_quat(yaw)

    # ------------------------------------------------------------------ point cloud
    def hover_points(self) -> np.ndarray:
        """All back-projected world points (M, 3) of the seven hovering depth views of the current state."""
        renderer = self._renderer(HOVER_SIZE, HOVER_SIZE, depth=True)
        far = self.model.vis.map.zfar * self.model.stat.extent
        clouds = []
        for cam in self.hover_cams:
            renderer.update_scene(self.data, camera=cam)
            depth = renderer.render()
            clouds.append(back_project(depth, self.data.cam_xpos[cam], self.data.cam_xmat[cam].reshape(3, 3),
                                       float(self.model.cam_fovy[cam]), 0.99 * far))
        return np.concatenate(clouds)

    def capture_point_cloud(self, rng: np.random.Generator) -> np.ndarray:
        """The hanger's point cloud (n_points, 3) float32: hovering views, box filter, fusion, subsampling."""
        points = self.hover_points()
        points = voxel_unique(points[in_boxes(points, self.boxes)], VOXEL)
        if len(points) == 0:
            raise RuntimeError(
                "no depth point fell inside the hanger box: the hovering views miss the hanger"
            )
        return farthest_point_sample(points, self.n_points, rng).astype(np.float32)

    # ------------------------------------------------------------------ observation
    def _entity_poses(self):
        if self.hanger_obs == "point_cloud":
            hanger = (self._cloud.mean(0).astype(np.float64), np.eye(3))
        else:
            hanger = self.body_pose(self.hanger_id)
        return [self.body_pose(self.mug_id), hanger]

    def _extra_observation_spaces(self) -> dict[str, spaces.Space]:
        if self.hanger_obs != "point_cloud":
            return {}
        bound = np.float32(POSITION_BOUND)
        return {"point_cloud": spaces.Box(-bound, bound, (self.n_points, 3), dtype=np.float32)}

    def _extra_observation(self) -> dict[str, np.ndarray]:
        return {"point_cloud": self._cloud.copy()} if self.hanger_obs == "point_cloud" else {}

    def mug_held(self) -> bool:
        """Both finger pads touch the mug: the grasp that switches on ``mask_after_grasp``'s mask."""
        return self.is_grasped(self.mug_geoms)

    def mug_mask(self) -> np.ndarray:
        """(image_size, image_size) bool: the wrist image's pixels that show the mug, from MuJoCo's
        segmentation rendering of the wrist camera in the current state."""
        ids = self._geom_ids(WRIST_CAMERA, self.image_size, self.image_size)
        return np.isin(ids, self.mug_geom_ids)

    def _camera_image(self, camera: str) -> np.ndarray:
        image = super()._camera_image(camera)
        if camera == "wrist" and self.mask_after_grasp and self.mug_held():
            image[~self.mug_mask()] = 0  # [H, W, 3]: everything but the mug black
        return image

    # ------------------------------------------------------------------ success
    def handle_on_peg(self) -> bool:
        """The peg's axis passes through the handle's opening: it crosses the handle's mid-plane (mug-frame
        y = 0) inside the opening's rectangle (2 mm of slack around it)."""
        pos, rot = self.body_pose(self.mug_id)
        h_pos, h_rot = self.body_pose(self.hanger_id)
        root, tip = ((h_pos + h_rot @ p - pos) @ rot for p in (PEG_ROOT, PEG_TIP))  # in the mug frame
        if root[1] * tip[1] > 0.0:
            return False
        cross = root + (tip - root) * (root[1] / (root[1] - tip[1]))
        slack = 0.002
        return bool(MUG_RADIUS - slack <= cross[0] <= MUG_RADIUS + HANDLE_GAP + slack
                    and HOLE_LOW - slack <= cross[2] <= HOLE_HIGH + slack)

    def mug_hanging(self) -> bool:
        """Right now the mug hangs by its handle: the peg goes through the handle, the mug touches the peg or
        the pole, and touches neither the table, the hanger's base plate nor the robot."""
        return bool(
            self.touching(self.mug_geoms, self.support_geoms)
            and not self.touching(self.mug_geoms, self.ground_geoms)
            and not self.touching(self.mug_geoms, self.robot_geoms)
            and self.handle_on_peg()
        )

    @property
    def hang_steps(self) -> int:
        """Consecutive control steps, up to now, at the end of which the mug was hanging."""
        return self._hang_steps

    def _after_reset(self) -> None:
        self._hang_steps = 0

    def _after_physics(self) -> None:
        # The one contact scan of a control step: the hang counter advances after the physics.
        self._hang_steps = self._hang_steps + 1 if self.mug_hanging() else 0

    def _check_success(self) -> bool:
        # A count of HANG_STEPS means the mug hung at the end of each of the last HANG_STEPS steps.
        return self._hang_steps >= HANG_STEPS
