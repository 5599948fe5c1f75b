"""Three Piece Assembly (MimicGen): insert piece 1 into the base's socket, then piece 2 onto piece 1."""

from __future__ import annotations

import mujoco
import numpy as np

from gym_actionflow.base import ROBOT_BASE, TABLE_TOP, ManipulationEnv
from gym_actionflow.geometry import yaw_quat
from gym_actionflow.placement import Region, square

# ---------------------------------------------------------------- geometry (metres, half sizes unless noted)
BASE_HALF = 0.09
"""The base is an 18 cm square frame (MimicGen: 5 x 5 blocks of 3.8 cm = 19 cm)."""
BASE_HEIGHT = 0.03
"""Height of the base frame = depth of the socket (MimicGen: 3.8 cm)."""
SOCKET_HALF = 0.058
"""The socket is an 11.6 cm square hole through the frame, down to the table (MimicGen: 3 x 3 blocks,
11.4 cm)."""
LEAD_IN = 0.008
"""The socket's rim carries a 45-degree chamfer this wide and high (a bar turned 45 degrees on each edge)."""
SLAB_HALF = 0.05
"""Piece 1's slab is a 10 cm square (MimicGen: 3 x 3 blocks of 3.4 cm = 10.2 cm): 8 mm clearance per side."""
SLAB_HEIGHT = 0.04
"""Piece 1's slab is 4 cm thick, so it stands 1 cm proud of the frame once seated and carries piece 2."""
RIDGE_HALF = (0.015, 0.045)
"""Piece 1's ridge (the handle, and the peg of piece 2's slot): 3 cm wide (x) by 9 cm long (y) in the piece
frame (MimicGen: a 1 x 3 row of 0.9-scaled 3.4 cm blocks)."""
RIDGE_HEIGHT = 0.05
PIECE2_HALF = 0.05
"""Piece 2's footprint is a 10 cm square (MimicGen: 3 x 3 blocks of 4 cm = 12 cm)."""
RAIL_WIDTH = 0.03
"""Piece 2 stands on two 3 cm wide rails along its y axis; the slot between them is 4 cm wide, 5 mm of
clearance per side around the 3 cm ridge (MimicGen: two rows of blocks with a one-block gap)."""
RAIL_HEIGHT = 0.055
"""Rails are taller than the ridge (5 cm), so a seated piece 2 rests on the slab, not on the ridge."""
PLATE_HEIGHT = 0.03
KNOB_HALF = 0.02
"""Piece 2's handle: a 4 cm square knob on top of its plate (MimicGen: one 4 cm block)."""
KNOB_HEIGHT = 0.05
DENSITY = 100.0
"""kg/m^3 of the pieces, as in MimicGen (piece 1 weighs 54 g, piece 2 71 g)."""

PIECE1_HEIGHT = SLAB_HEIGHT + RIDGE_HEIGHT
PIECE2_HEIGHT = RAIL_HEIGHT + PLATE_HEIGHT + KNOB_HEIGHT

# ---------------------------------------------------------------- initial state
BASE_D0 = (0.0, 0.0)
"""The base's xy in D0 (yaw 0): the table centre, as in MimicGen."""
RANGE = 0.22
"""Pieces (and in D1 the base) are placed with x, y uniform in +-0.22 m, as in MimicGen."""
PIECE_YAW = np.pi / 2
"""Both pieces start with yaw pi/2 and the base with yaw 0, as in MimicGen D0 and D1."""
BASE_YAW = {"D0": (0.0, 0.0), "D1": (0.0, 0.0), "D2": (-np.pi / 4, np.pi / 4)}
PIECE_YAWS = {"D0": (PIECE_YAW, PIECE_YAW), "D1": (PIECE_YAW, PIECE_YAW), "D2": (0.0, np.pi)}
"""Yaw ranges of the base and of both pieces per variant (MimicGen's). In D2 the base turns by up to 45
degrees either way and the pieces by up to 90 degrees about pi/2: with the square socket's quarter-turn and
the pieces' half-turn symmetry, every heading of every object is possible."""
CLEARANCE = 0.01
"""Extra gap (m) between the footprints of the objects at reset."""
REACH = 0.77
"""Objects are placed at most this far (xy) from the robot base, which cuts the two far corners of the
+-0.22 m square: beyond it the arm cannot hold a carried piece at transit height (MimicGen's robot stands on
a mount)."""

# ---------------------------------------------------------------- success
XY_TOL = 0.02
"""A piece must be within 2 cm (xy) of its seat (MimicGen's threshold)."""
Z_TOL = 0.005
"""... and within 5 mm of its seated height (fully inserted)."""
UPRIGHT = 0.95
"""... and upright: cosine of its tilt above this (about 18 degrees)."""

_WOOD = {"base": (0.45, 0.3, 0.18, 1), "piece_1": (0.8, 0.25, 0.15, 1), "piece_2": (0.25, 0.45, 0.8, 1)}
_FRICTION = (1.0, 0.005, 0.0001)


def _box(body: mujoco.MjsBody, name: str, half, pos, rgba, density: float = DENSITY) -> None:
    body.add_geom(name=name, type=mujoco.mjtGeom.mjGEOM_BOX, size=half, pos=pos, rgba=rgba, density=density,
                  friction=_FRICTION, condim=4)


def sample_reachable(
    rng: np.random.Generator, regions: list[Region], radii: list[float],
    fixed: list[tuple[np.ndarray, float]] = (), max_tries: int = 1000,
) -> list[tuple[np.ndarray, float]]:
    """Like ``placement.sample_separated`` (one (xy, yaw) per region, discs of the given radii not overlapping
    each other or the ``fixed`` discs), and each centre within ``REACH`` of the robot base."""
    placed: list[tuple[np.ndarray, float]] = []
    discs = [(np.asarray(c, dtype=float), r) for c, r in fixed]
    robot = np.asarray(ROBOT_BASE[:2])
    for region, radius in zip(regions, radii, strict=True):
        for _ in range(max_tries):
            xy, yaw = region.sample(rng)
            reachable = np.linalg.norm(xy - robot) <= REACH
            if reachable and all(np.linalg.norm(xy - c) > radius + r for c, r in discs):
                break
        else:
            raise RuntimeError(f"could not place an object of radius {radius} in {region} after {max_tries} "
                               "tries")
        placed.append((xy, yaw))
        discs.append((xy, radius))
    return placed


class ThreePieceAssemblyEnv(ManipulationEnv):
    """Assemble three pieces: piece 1 (red) into the socket of the base, then piece 2 (blue) onto piece 1.

    MimicGen's Three Piece Assembly task, rebuilt on raw MuJoCo with box primitives. The base is an 18 cm
    square frame, 3 cm high, around an 11.6 cm square socket that goes down to the table, its rim chamfered
    (8 mm). Piece 1 is a 10 cm square slab, 4 cm thick, with a ridge on top (3 x 9 cm, 5 cm high) that serves
    as its handle. Piece 2 stands on two rails with a 4 cm slot between them that fits over the ridge; on its
    plate sits a 4 cm square knob, 5 cm high, its handle. Clearances are 8 mm per side (slab in socket) and
    5 mm per side (ridge in slot). Body origins (and token positions) are at the centre of each part's bottom
    face.

    ## Observation
    | key | shape | content |
    |---|---|---|
    | `token_poses` | (4, 9) | world poses: 0 = EEF (TCP), 1 = base, 2 = piece 1, 3 = piece 2 |
    | `token_features` | (4, 5) | one-hot token id (4) + gripper opening in m (EEF row only) |
    | `agent_pos` | (10,) | EEF pose (9) + gripper opening |
    | `environment_state` | (27,) | poses of the base, piece 1, piece 2 |
    | `pixels` | {"wrist": (84, 84, 3) uint8} | only with `obs_mode="pixels"` |

    Pose vectors are `[x, y, z, r00, r10, r20, r01, r11, r21]` (position + first two rotation columns).

    ## Action
    (10,) float32: absolute target TCP pose (9, world frame) + gripper command in [-1 open, 1 close]. The
    rotation is orthonormalised, the position clipped to the workspace and each step rate-limited to
    3 cm / 0.3 rad.

    ## Success
    Piece 1 is in the socket: its xy within 2 cm of the base's, its bottom within 5 mm of the table (fully
    inserted), upright, and not held by the gripper. Piece 2 is on piece 1: its xy within 2 cm of piece 1's,
    its bottom within 5 mm of the top of piece 1's slab (so its slot is over the ridge), upright, and not
    held.

    ## Starting state
    The arm at its home pose, gripper open. MimicGen's ThreePieceAssembly_D0 / D1 / D2 ranges:

    | variant | base x, y | base yaw | pieces x, y | pieces yaw |
    |---|---|---|---|---|
    | `"D0"` | (0, 0) | 0 | +-0.22 m | pi/2 |
    | `"D1"` | +-0.22 m | 0 | +-0.22 m | pi/2 |
    | `"D2"` | +-0.22 m | [-pi/4, pi/4] | +-0.22 m | [0, pi] (pi/2 +- pi/2) |

    The base is a static fixture moved at reset; the pieces lie on the table, not overlapping each other or
    the base, each piece's yaw drawn on its own. With the socket's quarter-turn symmetry and the pieces'
    half-turn symmetry, D2 covers every heading of every object: piece 1 has to be turned to the base (by
    up to 45 degrees) and piece 2 to piece 1 (by up to 90 degrees). One difference from MimicGen: every
    object's centre is at most 0.77 m from the robot base, which cuts the far corners of the square; there the
    arm cannot hold a carried piece at transit height (MimicGen's robot stands on a mount).

    ## Episode end
    Terminates on success (unless `terminate_on_success=False`); truncated after `max_episode_steps` (500).

    ## Version history
    * v0: initial release.
    * v0, issue 13: variant D2 (MimicGen's ThreePieceAssembly_D2); D0 and D1 unchanged.
    """

    variants = ("D0", "D1", "D2")
    entity_names = ("base", "piece_1", "piece_2")
    task_description = "Insert the red piece into the base, then put the blue piece on top of the red piece."

    def _build_task(self, spec: mujoco.MjSpec) -> None:
        # Base: a static frame of four boxes around the socket (moved at reset in D1).
        base = spec.worldbody.add_body(name="base", pos=(*BASE_D0, TABLE_TOP))
        wall = (BASE_HALF - SOCKET_HALF) / 2
        mid = (BASE_HALF + SOCKET_HALF) / 2
        hz = BASE_HEIGHT / 2
        rgba = _WOOD["base"]
        _box(base, "base_wall_px", (wall, BASE_HALF, hz), (mid, 0, hz), rgba)
        _box(base, "base_wall_nx", (wall, BASE_HALF, hz), (-mid, 0, hz), rgba)
        _box(base, "base_wall_py", (SOCKET_HALF, wall, hz), (0, mid, hz), rgba)
        _box(base, "base_wall_ny", (SOCKET_HALF, wall, hz), (0, -mid, hz), rgba)
        # Chamfer: a square bar turned 45 degrees along each rim edge, its inner corner on the socket's edge.
        h = LEAD_IN / np.sqrt(2)
        c = SOCKET_HALF + LEAD_IN
        about_y = (np.cos(np.pi / 8), 0, np.sin(np.pi / 8), 0)
        about_x = (np.cos(np.pi / 8), np.sin(np.pi / 8), 0, 0)
        for name, pos, quat, half in (
            ("px", (c, 0, BASE_HEIGHT), about_y, (h, c, h)), ("nx", (-c, 0, BASE_HEIGHT), about_y, (h, c, h)),
            ("py", (0, c, BASE_HEIGHT), about_x, (c, h, h)), ("ny", (0, -c, BASE_HEIGHT), about_x, (c, h, h)),
        ):
            base.add_geom(name=f"base_chamfer_{name}", type=mujoco.mjtGeom.mjGEOM_BOX, size=half, pos=pos,
                          quat=quat, rgba=rgba, friction=_FRICTION, condim=4)

        # Piece 1: slab + ridge along its y axis.
        p1 = spec.worldbody.add_body(name="piece_1")
        p1.add_freejoint(name="piece_1_joint")
        rgba = _WOOD["piece_1"]
        _box(p1, "piece_1_slab", (SLAB_HALF, SLAB_HALF, SLAB_HEIGHT / 2), (0, 0, SLAB_HEIGHT / 2), rgba)
        _box(p1, "piece_1_ridge", (*RIDGE_HALF, RIDGE_HEIGHT / 2), (0, 0, SLAB_HEIGHT + RIDGE_HEIGHT / 2),
             rgba)

        # Piece 2: two rails along its y axis, a plate, a knob.
        p2 = spec.worldbody.add_body(name="piece_2")
        p2.add_freejoint(name="piece_2_joint")
        rgba = _WOOD["piece_2"]
        rail_x = PIECE2_HALF - RAIL_WIDTH / 2
        rail = (RAIL_WIDTH / 2, PIECE2_HALF, RAIL_HEIGHT / 2)
        _box(p2, "piece_2_rail_px", rail, (rail_x, 0, RAIL_HEIGHT / 2), rgba)
        _box(p2, "piece_2_rail_nx", rail, (-rail_x, 0, RAIL_HEIGHT / 2), rgba)
        _box(p2, "piece_2_plate", (PIECE2_HALF, PIECE2_HALF, PLATE_HEIGHT / 2),
             (0, 0, RAIL_HEIGHT + PLATE_HEIGHT / 2), rgba)
        _box(p2, "piece_2_knob", (KNOB_HALF, KNOB_HALF, KNOB_HEIGHT / 2),
             (0, 0, RAIL_HEIGHT + PLATE_HEIGHT + KNOB_HEIGHT / 2), rgba)

    def _cache_refs(self) -> None:
        m = self.model
        self.base_id = m.body("base").id
        self.piece_ids = {n: m.body(n).id for n in ("piece_1", "piece_2")}
        self.piece_geoms = {n: self.geoms_of(n) for n in ("piece_1", "piece_2")}

    def _sample_layout(self, rng: np.random.Generator) -> None:
        base_r = BASE_HALF * np.sqrt(2) + CLEARANCE
        r1 = SLAB_HALF * np.sqrt(2) + CLEARANCE
        r2 = PIECE2_HALF * np.sqrt(2) + CLEARANCE
        region = square(RANGE, yaw=PIECE_YAWS[self.variant])
        if self.variant == "D0":
            base_xy, base_yaw = np.array(BASE_D0), 0.0
            placed = sample_reachable(rng, [region, region], [r1, r2], fixed=[(base_xy, base_r)])
        else:
            base_region = square(RANGE, yaw=BASE_YAW[self.variant])
            regions = [base_region, region, region]
            (base_xy, base_yaw), *placed = sample_reachable(rng, regions, [base_r, r1, r2])
        self.model.body_pos[self.base_id] = (base_xy[0], base_xy[1], TABLE_TOP)
        self.model.body_quat[self.base_id] = yaw_quat(base_yaw)
        for name, (xy, piece_yaw) in zip(("piece_1", "piece_2"), placed, strict=True):
            self.set_free_pose(f"{name}_joint", np.array([xy[0], xy[1], TABLE_TOP]), yaw_quat(piece_yaw))

    def _entity_poses(self):
        return [self.body_pose(self.base_id), *(self.body_pose(i) for i in self.piece_ids.values())]

    # ---------------------------------------------------------------- success
    def _seated(self, name: str, seat_xy: np.ndarray, seat_z: float) -> bool:
        pos, rot = self.body_pose(self.piece_ids[name])
        return bool(
            np.linalg.norm(pos[:2] - seat_xy) < XY_TOL
            and abs(pos[2] - seat_z) < Z_TOL
            and rot[2, 2] > UPRIGHT
            and not self.is_grasped(self.piece_geoms[name])
        )

    def piece_1_assembled(self) -> bool:
        """Piece 1 in the socket: its bottom on the table, like the base's."""
        base_pos = self.data.xpos[self.base_id]
        return self._seated("piece_1", base_pos[:2], base_pos[2])

    def piece_2_assembled(self) -> bool:
        """Piece 2 on piece 1, its bottom on top of the slab (whether or not piece 1 is in the base)."""
        p1 = self.data.xpos[self.piece_ids["piece_1"]]
        return self._seated("piece_2", p1[:2], p1[2] + SLAB_HEIGHT)

    def _check_success(self) -> bool:
        return self.piece_1_assembled() and self.piece_2_assembled()
