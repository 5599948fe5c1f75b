"""Lightbulb's socket fits (`socket_fit`): the default is today's strict socket, unchanged; "paper" widens the
bore and the entry slots by the calibrated clearance, so an insertion about a millimetre off that jams on the
strict socket goes in; a bad name is refused; the env config passes the option through."""

from __future__ import annotations

from dataclasses import dataclass

import draccus
import gym_actionflow
import gymnasium as gym
import numpy as np
import pytest
from gym_actionflow.tasks.lightbulb import (
    BORE_RADIUS,
    CAP_RADIUS,
    CLEARANCE,
    PAPER_CLEARANCE,
    PIN_HALF,
    SLOT_HALF_WIDTH,
    SOCKET_TOP,
    SocketFit,
)
from gymnasium.utils.env_checker import check_env
from lerobot.envs.configs import EnvConfig

from lerobot_actionflow.env_config import ActionFlowEnvConfig

ENV_ID = "gym_actionflow/Lightbulb-v0"


@dataclass
class _EvalArgs:
    """lerobot-eval's ``--env.*`` arguments, as draccus parses them."""

    env: EnvConfig | None = None


def socket_faces(env: gym.Env) -> tuple[float, float]:
    """The bore's radius and the entry slot's half width, read from the compiled model: the inner face of
    the first upper-ring wall box (its centre's distance from the axis minus its radial half extent) and
    the inner face of slot 0's front wall (slot 0 lies along the socket's x axis, so its walls face y)."""
    model = env.unwrapped.model
    arc = model.geom("socket_upper0_0")
    front = model.geom("socket_slot0_front")
    bore = np.hypot(*arc.pos[:2]) - arc.size[0]
    slot_half = front.pos[1] - front.size[1]
    return float(bore), float(slot_half)


def test_the_default_fit_is_the_strict_socket_unchanged():
    """Guards against the new keyword moving the default geometry: without `socket_fit` (and with
    "strict") the bore and the slots are the strict constants' (1.5 mm of clearance), and every geom of the
    two models is the same, bit for bit."""
    default = gym.make(ENV_ID)
    strict = gym.make(ENV_ID, socket_fit="strict")
    assert CLEARANCE == 0.0015
    bore, slot_half = socket_faces(default)
    assert bore == pytest.approx(BORE_RADIUS, abs=1e-12) and BORE_RADIUS == CAP_RADIUS + 0.00075
    assert slot_half == pytest.approx(SLOT_HALF_WIDTH, abs=1e-12) and SLOT_HALF_WIDTH == PIN_HALF[1] + 0.00075
    a, b = default.unwrapped.model, strict.unwrapped.model
    for field in ("geom_size", "geom_pos", "geom_quat", "body_pos"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)
    default.close()
    strict.close()


def test_the_paper_fit_widens_the_bore_and_the_slots_by_the_calibrated_clearance():
    """The paper fit has 2.5 mm of total clearance (the value eval/results/lightbulb_fit.md chose), 0.5 mm a
    side more than the strict one, in the bore and in the slots alike; the bulb and the rest of the scene are
    as before."""
    assert PAPER_CLEARANCE == 0.0025
    paper = gym.make(ENV_ID, socket_fit="paper")
    strict = gym.make(ENV_ID)
    bore, slot_half = socket_faces(paper)
    assert bore == pytest.approx(BORE_RADIUS + 0.0005, abs=1e-12)
    assert slot_half == pytest.approx(SLOT_HALF_WIDTH + 0.0005, abs=1e-12)
    a, b = paper.unwrapped, strict.unwrapped
    assert a.model.ngeom == b.model.ngeom
    others = sorted(set(range(a.model.ngeom)) - a.socket_geoms)  # the bulb, the robot, the table
    assert len(a.socket_geoms) > 20 and a.bulb_geoms <= set(others)
    np.testing.assert_array_equal(a.model.geom_size[others], b.model.geom_size[others])
    np.testing.assert_array_equal(a.model.geom_pos[others], b.model.geom_pos[others])
    paper.close()
    strict.close()


def test_a_bad_fit_is_refused_with_the_keyword_the_value_and_the_choices():
    """An unknown name names `socket_fit`, the value and the choices; a clearance that would let a pin slip
    out from under the ring is refused with its range."""
    with pytest.raises(ValueError, match=r"socket_fit='loose'; expected one of \('strict', 'paper'\)"):
        gym.make(ENV_ID, socket_fit="loose")
    with pytest.raises(ValueError, match=r"SocketFit\(clearance=0\.004\); expected .* between 0 and 0\.0035"):
        SocketFit(0.004)


@pytest.mark.parametrize("offset_mm", [(1.1, 0.0), (-1.1, 0.0), (0.0, 1.1), (0.0, -1.1)],
                         ids=["+x", "-x", "+y", "-y"])  # fmt: skip
def test_an_insertion_1_1_mm_off_jams_on_the_strict_socket_and_goes_in_on_the_paper_one(offset_mm):
    """What the fit is for: the deterministic expert's insertion shifted 1.1 mm (along the slots or across
    them, either way, socket frame) lands on the strict socket's rim and stays there (the expert turns it on
    the rim: no success); on the paper socket the same episode seats and locks the bulb. Guards against a
    "paper" fit that does not forgive more than the strict one."""
    offset = np.array([offset_mm[0], offset_mm[1], 0.0]) / 1000
    for fit, succeeds in (("strict", False), ("paper", True)):
        env = gym.make(ENV_ID, socket_fit=fit)
        expert = gym_actionflow.make_expert(env, noise=0.0, seed=0)
        expert.insertion_offset = offset
        episode = gym_actionflow.run_episode(env, expert, 0)
        depth = env.unwrapped.bulb_in_socket()[0][2]
        assert episode.success is succeeds, fit
        if succeeds:
            assert abs(depth) < 0.001, "the bulb should be seated on the floor"
        else:
            assert depth > SOCKET_TOP - 0.002, "the bulb should be stuck on the rim, not inserted"
        env.close()


def test_the_paper_fit_passes_check_env():
    env = gym.make(ENV_ID, socket_fit="paper")
    check_env(env.unwrapped)
    env.close()


def test_env_config_passes_socket_fit_like_lerobot_eval_parses_it():
    """`--env.socket_fit=paper` reaches gym.make, as lerobot-eval parses it (draccus); left out, the env's
    default stays; on another task it is refused."""
    args = ["--env.type=actionflow", "--env.task=Lightbulb-v0", "--env.socket_fit=paper"]
    config = draccus.parse(_EvalArgs, args=args).env
    assert config.gym_kwargs == {"variant": "D0", "obs_mode": "state", "socket_fit": "paper"}
    assert "socket_fit" not in ActionFlowEnvConfig(task="Lightbulb-v0").gym_kwargs
    with pytest.raises(ValueError, match="--env.socket_fit is a Lightbulb option; the task is MugHanging"):
        ActionFlowEnvConfig(task="MugHanging-v0", socket_fit="paper")


def test_the_fit_diagnostic_prints_a_row_per_fit(capsys):
    """`python -m eval.diagnostics.lightbulb_fit` (the measurement behind eval/results/lightbulb_fit.md) runs
    end to end on two episodes: unshifted replays are exact, so that column reads 100 %; a candidate
    clearance it cannot build is refused with the flag, the value and the range."""
    from eval.diagnostics.lightbulb_fit import main, parse_fit

    main(["--socket-fit", "paper", "--episodes", "2"])
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| paper |")]
    assert rows and rows[-1].startswith("| paper | 2.5 mm | fixed | 2 | 2 | 100% |")
    assert parse_fit("2.25") == ("2.25 mm", SocketFit(0.00225))
    with pytest.raises(ValueError, match=r"--socket-fit='4': SocketFit\(clearance=0\.004\); expected"):
        parse_fit("4")
    with pytest.raises(ValueError, match=r"--socket-fit='loose'; expected one of \('strict', 'paper'\)"):
        parse_fit("loose")
