"""Scripted expert for Lightbulb: carry the held bulb over the socket with its pins aligned to the entry
slots, servo it onto the socket axis, lower it in, then turn it 67 degrees about the socket axis to lock it.

Every TCP target is computed from the bulb pose it should put the bulb at and the bulb's in-hand pose (the
bulb-in-TCP transform, re-measured before each phase), so it is the bulb, not the hand, that is aligned.
Over the socket the expert closes the loop on the bulb's measured pose (its xy and yaw before the insertion,
its xy while lowering it until the cap enters the bore); an insertion that jams is retried twice.

``noise`` (0 deterministic, 1 the suite's reference level): the carry waypoint gets the base offset
(``WAYPOINT_POS`` std), the insertion target a twentieth of it (``SEAT_OFFSET``), and the per-step jitter of
the emitted pose is the base jitter during the transit but ``FINE_JITTER`` times it while the bulb is aligned,
inserted and turned, since the clearance is 0.75 mm a side.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from gym_actionflow.experts.base import CLOSE, ScriptedExpert, object_in_tcp, symmetric_yaw, tcp_for_object
from gym_actionflow.geometry import yaw_matrix, yaw_of
from gym_actionflow.tasks.lightbulb import LOCK_ANGLE, SEAT_DEPTH_TOL, SOCKET_TOP, LightbulbEnv

CARRY_HEIGHT = 0.06
"""Height of the cap bottom above the socket floor while moving over the socket (the socket is 16.5 mm
tall)."""
PRE_ENTRY = SOCKET_TOP + 0.004
"""Height of the cap bottom above the floor where the bulb is aligned before going in (4 mm above the rim)."""
PUSH = 0.0005
"""The bulb is pushed to 0.5 mm below the floor (so it is pressed lightly onto it) and turned there."""
DESCENT_SPEED = 0.0015
DESCENT_RAMP = 6
"""Insertion speed, metres per control step, reached after a ramp of 6 steps."""
FEEDBACK_GAIN = 0.5
"""Fraction of the bulb's xy error corrected at each step of the insertion (above the rim)."""
JAM = 0.002
"""The insertion has jammed when the bulb lags the commanded depth by more than 2 mm."""
MAX_TRIES = 3
"""Insertion attempts (lift, re-align, lower again) before the expert gives up and turns the bulb anyway."""
SERVO_ROUNDS, SERVO_STEPS, SERVO_TOL, SERVO_YAW_TOL = 4, 3, 0.0002, np.deg2rad(0.5)
"""Over the socket: up to 4 corrections of the bulb's xy and yaw error (averaged over 3 steps) until under
0.2 mm and 0.5 degrees."""
TURN_STEPS = 24
TURN_EXTRA = np.deg2rad(3.0)
"""The turn: 67 degrees in 24 steps (about 2.8 degrees a step); if the bulb lags (it can creep in the fingers)
the hand keeps turning, up to 3 degrees more, until the bulb reaches 67 degrees (the end stop)."""
SEAT_OFFSET = 0.05
"""Scale of the random xy offset of the insertion target (std 0.2 mm at noise 1, truncated at 0.4 mm): the
clearance is 0.75 mm a side."""
FINE_JITTER = 0.1
"""Scale of the per-step action jitter while the bulb is aligned, inserted and turned (the approach keeps the
full jitter): at noise 1 the full jitter (2 mm std) is more than the clearance."""


class LightbulbExpert(ScriptedExpert):
    """``insertion_offset`` (3,) shifts the insertion pose by a fixed offset in the socket frame (metres):
    e.g. ``[0, 0.0015, 0]`` moves it 1.5 mm across the slots, which makes the insertion jam (see the
    tests)."""

    env: LightbulbEnv

    def __init__(self, env: gym.Env, noise: float = 0.0, seed: int | None = None,
                 insertion_offset=None) -> None:
        super().__init__(env, noise=noise, seed=seed)
        offset = np.zeros(3) if insertion_offset is None else insertion_offset
        self.insertion_offset = np.asarray(offset, dtype=float)

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self.grip = CLOSE  # the bulb starts in the hand: keep holding it

    # ------------------------------------------------------------------ measurements
    def bulb_pose(self) -> tuple[np.ndarray, np.ndarray]:
        return self.env.body_pose(self.env.bulb_id)

    def in_hand(self) -> tuple[np.ndarray, np.ndarray]:
        return object_in_tcp(self.env, self.env.bulb_id)

    def script(self):
        env = self.env
        s_pos, s_rot = env.body_pose(env.socket_id)
        grasp = self.in_hand()
        # Pin 1 goes into the slot (of the two, equivalent under a half turn) that keeps the wrist nearest its
        # home yaw over the turn: the TCP yaw is the bulb's yaw plus a fixed in-hand offset.
        hand_yaw = yaw_of(tcp_for_object(np.zeros(3), np.eye(3), grasp)[1])
        entry_yaw = symmetric_yaw(yaw_of(s_rot), np.pi, reference=-hand_yaw - LOCK_ANGLE / 2)
        seat = s_pos + s_rot @ self.insertion_offset
        entry_rot = yaw_matrix(entry_yaw)

        carry = seat + [0.0, 0.0, CARRY_HEIGHT] + self.offset() * np.array([1.0, 1.0, 0.5])
        yield from self.move_to(*tcp_for_object(carry, entry_rot, grasp))
        seat = seat + np.append(self.offset(SEAT_OFFSET)[:2], 0.0)
        for attempt in range(MAX_TRIES):
            grasp = self.in_hand()  # re-read how the bulb sits in the hand after the transit / a retry
            self.jitter_scale = 1.0
            yield from self.move_to(*tcp_for_object(seat + [0, 0, PRE_ENTRY], entry_rot, grasp), speed=0.01)
            self.jitter_scale = FINE_JITTER
            yield from self.align(seat[:2], entry_yaw)
            seated = yield from self.insert(seat)
            if seated or attempt == MAX_TRIES - 1:
                break
            yield from self.move_to(self.cmd_pos + [0, 0, PRE_ENTRY], self.cmd_rot, speed=0.005)
        yield from self.turn(entry_yaw)
        yield from self.hold(30)

    def align(self, target_xy: np.ndarray, target_yaw: float):
        """Closed loop on the bulb itself: average its xy and yaw error over a few steps and move the hand to
        cancel it (the arm's tracking error and in-hand creep would otherwise eat up the clearance)."""
        for _ in range(SERVO_ROUNDS):
            err_xy, err_yaw = np.zeros(2), 0.0
            for _ in range(SERVO_STEPS):
                yield self._action()
                pos, rot = self.bulb_pose()
                err_xy += (target_xy - pos[:2]) / SERVO_STEPS
                err_yaw += ((target_yaw - yaw_of(rot) + np.pi) % (2 * np.pi) - np.pi) / SERVO_STEPS
            if np.linalg.norm(err_xy) < SERVO_TOL and abs(err_yaw) < SERVO_YAW_TOL:
                break
            # Turn the hand about the bulb axis by the yaw error, then shift it by the xy error.
            pos = self.bulb_pose()[0]
            turn = yaw_matrix(err_yaw)
            goal_pos = pos + turn @ (self.cmd_pos - pos) + np.append(err_xy, 0.0)
            yield from self.move_to(goal_pos, turn @ self.cmd_rot, speed=0.004, max_wait=0)

    def insert(self, seat: np.ndarray):
        """Lower the aligned bulb straight down until it is pressed onto the floor; stop early when it jams
        (it lags the commanded depth). Until the cap enters the bore, each step also shifts the hand by a
        fraction of the bulb's xy error (the arm's lag while moving shifts the bulb sideways by a few tenths
        of a millimetre). Returns whether it is seated."""
        start_z = self.bulb_pose()[0][2] - seat[2]
        # Depth profile: the speed ramps up over the first steps (a sudden start shakes the bulb sideways).
        speeds = DESCENT_SPEED * np.minimum(1.0, np.arange(1, 200) / DESCENT_RAMP)
        depths = np.maximum(start_z - np.cumsum(speeds), -PUSH)
        depths = depths[: int(np.argmax(depths <= -PUSH)) + 1]
        base = self.cmd_pos.copy()
        shift = np.zeros(3)
        for commanded in depths:
            pos = self.bulb_pose()[0]
            if pos[2] - seat[2] > SOCKET_TOP:
                shift[:2] += FEEDBACK_GAIN * (seat[:2] - pos[:2])
            self.cmd_pos = base + shift - [0.0, 0.0, start_z - commanded]
            yield self._action()
            if self.bulb_pose()[0][2] - seat[2] - commanded > JAM:
                return False
        for _ in range(10):
            if self.bulb_pose()[0][2] - seat[2] < 0.5 * SEAT_DEPTH_TOL:
                return True
            yield self._action()
        return bool(self.bulb_pose()[0][2] - seat[2] < 0.5 * SEAT_DEPTH_TOL)

    def turn(self, entry_yaw: float):
        """Turn the bulb 67 degrees counter-clockwise about its (= the socket's) axis, in small steps; the TCP
        follows from the bulb's in-hand pose, so it rotates about the bulb axis, not its own."""
        env = self.env
        grasp = self.in_hand()
        centre = self.bulb_pose()[0] - [0.0, 0.0, PUSH]

        def command(angle: float) -> None:
            self.cmd_pos, self.cmd_rot = tcp_for_object(centre, yaw_matrix(entry_yaw + angle), grasp)

        for k in range(1, TURN_STEPS + 1):
            s = k / TURN_STEPS
            command(LOCK_ANGLE * s * s * (3 - 2 * s))
            yield self._action()
        # The bulb may lag (creep in the fingers): keep turning a little until it reaches the end stop.
        extra = 0.0
        for _ in range(8):
            yield self._action()
            if env.bulb_angle() >= LOCK_ANGLE - np.deg2rad(1.0) or extra >= TURN_EXTRA:
                break
            extra = min(extra + np.deg2rad(1.0), TURN_EXTRA)
            command(LOCK_ANGLE + extra)
