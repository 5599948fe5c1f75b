"""eval/diagnostics/mug_trace.py reads the handle's opening in the hanger frame: the expert lines it up where
its script puts the insertion start."""

import gymnasium as gym
import numpy as np
import pytest
from gym_actionflow.tasks.mug_hanging import PEG_DIRECTION, PEG_TIP

from eval.diagnostics import mug_trace
from eval.diagnostics.mug_trace import APPROACH_START


def test_the_expert_lines_the_handle_up_at_its_insertion_start():
    """On a moved hanger whose mug starts beside the peg (the layouts policies fail)."""
    env = gym.make("gym_actionflow/MugHanging-v0", variant="test", mug_yaw="slight")
    hand: list = []
    path, success = mug_trace.run(env, 100011, None, max_steps=300, hand=hand)
    env.close()
    assert success
    assert path[0][2] < 0.1  # the mug stands on the table, below the peg
    point = mug_trace.lined_up(path)
    assert point is not None and abs(point[1]) < mug_trace.LINED_UP
    # The expert passes over the insertion start (5 cm beyond the tip) before lowering the handle onto it.
    start = PEG_TIP + 0.05 * PEG_DIRECTION
    assert np.isclose(APPROACH_START[0], start[0])
    assert abs(point[0] - start[0]) < 0.02 and point[2] > start[2]
    # One (gripper command, held) per step: the hand closed on the mug where it lines up, open once it hangs.
    assert len(hand) == len(path) - 1
    at = int(np.flatnonzero((path == point).all(axis=1))[0])
    assert hand[at - 1][0] > 0.5 and hand[at - 1][1]
    assert hand[-1][0] < -0.5 and not hand[-1][1]


def test_lined_up_is_the_first_lifted_step_near_the_peg_plane():
    path = np.array([[0.3, 0.0, 0.04], [0.25, 0.2, 0.2], [0.2, 0.005, 0.3], [0.15, 0.0, 0.3]])
    np.testing.assert_array_equal(mug_trace.lined_up(path), path[2])  # not the start, on the table
    assert mug_trace.lined_up(path[:2]) is None


def test_the_diagnosis_refuses_the_held_out_layouts(capsys):
    """What a diagnosis shows shapes the next setting: held-out seeds (from 200000) are refused by name
    before any checkpoint is loaded."""
    with pytest.raises(SystemExit):
        mug_trace.main(["no_checkpoint_needed", "--seeds", "100003", "200001"])
    err = capsys.readouterr().err
    assert "seeds [200001] are held-out layouts" in err and "100000-199999" in err
