"""ActionFlow's runtime options (latency compensation, action smoothing) under an injected inference delay.

    python -m eval.bench.delay --checkpoint outputs/demo_physics/train/checkpoints/last/pretrained_model \
        --task Stack --variant D0 --episodes 50 --delay-ms 0 50 100 200 measured --smoothing 0.5 \
        [--out eval/results]

In simulation inference is instantaneous for the env: the world waits for every chunk. A real robot does
not: with an asynchronous inference loop it keeps moving while the next chunk is computed. This benchmark
evaluates a trained policy under that timing, for every cell of delays x latency compensation {off, on} x
action smoothing {0, ``--smoothing``}, and writes a Markdown table to ``<out>/delay_<task>.md`` (default out:
``outputs/bench``).

Semantics (one control step = 1 / the env's control rate, 50 ms at 20 Hz), all in
:class:`DelayedPolicyRunner`:

* The delay is ``d = round(delay_s * control_fps)`` control steps; ``measured`` is the median time of the
  policy's ``predict_action_chunk`` on this machine (batch 1, after warm-up), rounded the same way.
* The policy is queried with the observation at step ``t`` whenever its action queue is empty (every
  ``n_action_steps`` executed actions of a chunk, as ``select_action`` does). Its chunk becomes available at
  step ``t + d``. Meanwhile the simulator executes ``d`` actions: the previous chunk's remaining actions
  (those after the ``n_action_steps`` its queue took), and, when they run out, the last executed action
  again (the robot holds its target). The observations of those ``d`` steps are not given to the policy.
* Latency compensation off: the first action executed from the new chunk (at step ``t + d``) is its action
  0, planned for step ``t``; each of its actions runs ``d`` steps late. On: the policy skips the ``d``
  actions whose time has passed and starts at action ``d`` (``select_action``'s own skip, see below).
* The policy measures the inference with its replaceable ``clock``; the runner takes that clock over and
  reports exactly ``d`` control periods (not wall time, not the unrounded ``delay_s``), so the policy's skip
  ``int(elapsed * control_fps)`` equals the ``d`` steps the simulator ran meanwhile, and every run is
  reproducible.
* The first chunk of an episode has no predecessor: the robot waits for it at rest, and the env is not
  stepped while it waits (episode lengths stay comparable; objects are at rest after the env's reset). The
  policy's clock still reports ``d``, so with compensation on it skips ``d`` actions of that chunk too, as
  it would on a robot.
* Action smoothing is an exponential filter over the executed command stream: the continuation actions
  go through the same ``smooth_action`` as the policy's outputs, and the first action of a new chunk is
  smoothed against the last action actually executed (the runner tells the policy that action with
  ``set_executed_action``). Delay 0 executes exactly what ``select_action`` returns.
* The observation history of a chunk is the observations of the last ``n_obs_steps`` ``select_action``
  calls; they are consecutive steps as long as ``n_action_steps >= n_obs_steps`` (2 <= 8 by default).

Metrics per cell over ``--episodes`` evaluation episodes from seed 100000 (``lerobot-eval --seed=100000``;
never a recording seed), the same seeds in every cell, torch's generator re-seeded per cell:

* success rate (the env's ``is_success`` at the end of the episode; episodes end on success or at the time
  limit);
* mean episode length in control steps (env steps; the wait for the first chunk is not a step);
* RMS jerk of the executed end-effector path: with ``p_k`` the EEF position in ``observation.state``
  (``agent_pos[:3]``, metres) after the reset (k = 0) and after each env step, the jerk is the third finite
  difference ``j_k = (p_{k+3} - 3 p_{k+2} + 3 p_{k+1} - p_k) * fps^3`` (m/s^3 at the control rate) and an
  episode's RMS jerk is ``sqrt(mean_k |j_k|^2)`` (Euclidean norm over x, y, z); the table gives the mean of
  the episodes' RMS jerk.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from gym_actionflow import find_task
from gym_actionflow.registry import make_env
from gym_actionflow.rollout import rollout
from torch import Tensor
from tqdm import tqdm

from eval.bench.output import add_out_argument, write_result
from eval.provenance import describe, portable, portable_command
from lerobot_actionflow import ActionFlowPolicy, schema
from lerobot_actionflow.modeling_actionflow import smooth_action
from lerobot_actionflow.recipes import EVAL_SEED

MEASURED = "measured"
"""``--delay-ms`` value: the policy's own median chunk time on this machine."""


def delay_steps(delay_s: float, control_fps: float) -> int:
    """The delay in whole control steps: ``round(delay_s * control_fps)``."""
    return round(delay_s * control_fps)


def reported_elapsed(steps: int, control_fps: float) -> float:
    """The elapsed time the policy's clock reports for a ``steps``-step delay: ``steps / control_fps``, or the
    next float above it where floating-point rounding would make the policy's ``int(elapsed * fps)`` one
    short."""
    elapsed = steps / control_fps
    while int(elapsed * control_fps) < steps:
        elapsed = math.nextafter(elapsed, math.inf)
    return elapsed


class DelayedPolicyRunner:
    """Drives an :class:`ActionFlowPolicy` as a robot with an asynchronous inference loop of ``delay``
    control steps (the module docstring gives the exact semantics).

    Call :meth:`reset` at every ``env.reset()`` and :meth:`act` once per env step with the current
    observation (a policy batch); it returns the action ``[B, 10]`` to execute at this step. The runner
    takes over the policy's clock, reads ``policy.last_chunk`` to see when a chunk arrives and tells the
    policy each executed action (``set_executed_action``, its smoothing state); the policy's config
    (``latency_compensation``, ``action_smoothing``) may change between episodes.
    """

    def __init__(self, policy: ActionFlowPolicy, delay: int):
        if delay < 0:
            raise ValueError(f"delay={delay}; expected a whole number of control steps >= 0")
        self.policy = policy
        self.delay = delay
        self._elapsed = reported_elapsed(delay, policy.config.control_fps)
        self._reads = 0
        policy.clock = self._clock
        self.reset()

    def reset(self) -> None:
        self.policy.reset()
        self._pending: deque[Tensor | None] = deque()
        """Raw actions to execute before the policy is asked again; None holds the last executed action."""
        self._last: Tensor | None = None
        """The last executed action ``[B, 10]``."""

    def _clock(self) -> float:
        """The policy's clock within one ``select_action`` call: 0 at its first read (the observation),
        ``d`` control periods at every later read (the chunk's arrival)."""
        self._reads += 1
        return 0.0 if self._reads == 1 else self._elapsed

    def act(self, batch: dict[str, Tensor]) -> Tensor:
        """The action ``[B, 10]`` executed at this step, given this step's observation."""
        if self._pending:  # inference under way: the previous chunk continues
            return self._execute(self._pending.popleft())
        previous = self.policy.last_chunk
        self._reads = 0
        action = self.policy.select_action(batch)
        new_chunk = self.policy.last_chunk is not previous
        if not (new_chunk and previous is not None and self.delay > 0):
            self._last = action
            return action
        # The new chunk arrives d steps from now; until then the previous chunk's remaining actions run.
        cfg = self.policy.config
        skip = min(self.delay, cfg.horizon - 1) if cfg.latency_compensation else 0  # select_action's skip
        start = skip + cfg.n_action_steps  # the previous chunk's first action its queue did not take
        remaining = [previous[:, i] for i in range(start, min(start + self.delay, cfg.horizon))]
        self._pending.extend(remaining + [None] * (self.delay - len(remaining)))
        self._pending.append(self.policy.last_chunk[:, skip])  # the new chunk's first action, unsmoothed
        return self._execute(self._pending.popleft())

    def _execute(self, raw: Tensor | None) -> Tensor:
        """Pass a raw action through the policy's smoothing, as executed after the last executed one."""
        alpha = self.policy.config.action_smoothing
        if raw is None:
            action = self._last
        elif alpha > 0 and self._last is not None:
            action = smooth_action(self._last, raw, alpha)
        else:
            action = raw
        self._last = action
        self.policy.set_executed_action(action)  # select_action smooths its next action against it
        return action


def rms_jerk(positions: np.ndarray, fps: float) -> float:
    """RMS jerk (m/s^3) of a path sampled at ``fps``: ``positions [T, 3]`` in metres, third finite
    difference ``[T - 3, 3]`` times ``fps^3``, root of the mean squared norm; NaN with fewer than 4 points."""
    if len(positions) < 4:
        return math.nan
    jerk = np.diff(np.asarray(positions, dtype=np.float64), n=3, axis=0) * fps**3  # [T - 3, 3]
    return float(np.sqrt(np.mean(np.sum(jerk**2, axis=1))))


@dataclass
class DelayedEpisode:
    success: bool
    steps: int
    jerk: float


@torch.no_grad()
def run_episode(env, runner: DelayedPolicyRunner, seed: int, fps: float) -> DelayedEpisode:
    """One evaluation episode of ``runner`` on ``env`` from ``seed`` (:func:`gym_actionflow.rollout.rollout`;
    the runner reset on the fresh state), with the RMS jerk of the EEF path from the reset on."""
    positions: list[np.ndarray] = []

    def start(obs: dict, info: dict) -> None:
        runner.reset()
        positions.append(obs["agent_pos"][:3])

    def moved(obs: dict, reward: float, terminated: bool, truncated: bool, info: dict) -> None:
        positions.append(obs["agent_pos"][:3])

    episode = rollout(env, lambda obs: runner.act(schema.policy_batch(obs))[0].numpy(), seed, on_reset=start,
                      after_step=moved)  # fmt: skip
    return DelayedEpisode(episode.success, episode.steps, rms_jerk(np.stack(positions), fps))


@torch.no_grad()
def measure_inference_s(
    policy: ActionFlowPolicy, batch: dict[str, Tensor], calls: int = 50, warmup: int = 10
) -> float:
    """Median wall time (s) of one ``predict_action_chunk`` on ``batch``, after ``warmup`` calls."""
    cuda = next(policy.parameters()).device.type == "cuda"
    times = []
    for i in range(warmup + calls):
        start = time.perf_counter()
        policy.predict_action_chunk(batch)
        if cuda:
            torch.cuda.synchronize()
        if i >= warmup:
            times.append(time.perf_counter() - start)
    return statistics.median(times)


def parse_delays(values: Sequence[str]) -> list[str | float]:
    """``--delay-ms`` values: milliseconds >= 0 or ``measured``."""
    delays: list[str | float] = []
    for value in values:
        if value == MEASURED:
            delays.append(MEASURED)
            continue
        try:
            ms = float(value)
        except ValueError:
            ms = -1.0
        if not ms >= 0:
            raise ValueError(f"--delay-ms {value!r}; expected milliseconds >= 0 or {MEASURED!r}")
        delays.append(ms)
    return delays


def table(rows: list[dict]) -> str:
    head = [
        "delay",
        "d (steps)",
        "latency compensation",
        "action smoothing",
        "success",
        "mean length (steps)",
        "RMS jerk (m/s^3)",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [
            r["delay"],
            str(r["d"]),
            "on" if r["compensation"] else "off",
            f"{r['smoothing']:g}",
            f"{r['success']:.0%} ({r['successes']}/{r['n']})",
            f"{r['mean_steps']:.1f}",
            f"{r['jerk']:.2f}",
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument(
        "--checkpoint", type=Path, required=True, help="a saved ActionFlow pretrained_model folder"
    )
    p.add_argument("--task", default="Stack")
    p.add_argument("--variant", default="D0")
    p.add_argument("--episodes", type=int, default=50, help="evaluation episodes per cell")
    p.add_argument(
        "--delay-ms",
        nargs="+",
        default=["0", "50", "100", "200", MEASURED],
        help=f"inference delays in ms, or {MEASURED!r} (the policy's median chunk time here)",
    )
    p.add_argument(
        "--smoothing",
        type=float,
        default=0.5,
        help="the action_smoothing of the smoothed cells (the others have 0)",
    )
    add_out_argument(p)
    p.add_argument("--note", default="", help="a line added under the table")
    args = p.parse_args(argv)
    delays = parse_delays(args.delay_ms)
    if not 0 < args.smoothing < 1:
        raise ValueError(f"--smoothing {args.smoothing}; expected an action_smoothing in (0, 1)")
    if args.episodes < 1:
        raise ValueError(f"--episodes {args.episodes}; expected at least 1")

    torch.set_num_threads(1)
    policy = ActionFlowPolicy.from_pretrained(args.checkpoint).eval()
    spec, env = find_task(args.task), make_env(args.task, args.variant)
    fps = float(env.metadata["render_fps"])
    if policy.config.control_fps != fps:
        raise ValueError(
            f"the policy's control_fps={policy.config.control_fps} but {spec.env_id} runs at {fps} Hz; "
            "expected the same rate (a delay in steps would mean different times to the policy and the env)"
        )
    obs, _ = env.reset(seed=EVAL_SEED)
    measured_s = measure_inference_s(policy, schema.policy_batch(obs)) if MEASURED in delays else None
    load = os.getloadavg()[0]  # the measured delay depends on what else the machine runs

    cells = []
    for delay in delays:
        delay_s = measured_s if delay == MEASURED else delay / 1000
        label = f"measured {measured_s * 1000:.1f} ms" if delay == MEASURED else f"{delay:g} ms"
        for compensation in (False, True):
            for smoothing in (0.0, args.smoothing):
                cells.append((label, delay_steps(delay_s, fps), compensation, smoothing))

    rows = []
    bar = tqdm(total=len(cells) * args.episodes, desc="episodes", mininterval=2)
    for label, d, compensation, smoothing in cells:
        bar.set_postfix_str(f"{label}, comp {'on' if compensation else 'off'}, smoothing {smoothing:g}")
        policy.config.latency_compensation, policy.config.action_smoothing = compensation, smoothing
        runner = DelayedPolicyRunner(policy, d)
        torch.manual_seed(EVAL_SEED)
        episodes = []
        for i in range(args.episodes):
            episodes.append(run_episode(env, runner, EVAL_SEED + i, fps))
            bar.update()
        successes = sum(e.success for e in episodes)
        rows.append(
            dict(
                delay=label,
                d=d,
                compensation=compensation,
                smoothing=smoothing,
                successes=successes,
                n=len(episodes),
                success=successes / len(episodes),
                mean_steps=float(np.mean([e.steps for e in episodes])),
                jerk=float(np.nanmean([e.jerk for e in episodes])),
            )
        )
    bar.close()
    env.close()

    given = argv if argv is not None else sys.argv[1:]
    command = portable_command(["python", "-m", "eval.bench.delay", *given])
    cfg = policy.config
    lines = [
        f"# ActionFlow under an inference delay: {spec.name} {args.variant}",
        "",
        f"Command: `{command}`",
        "",
        f"Checkpoint `{portable(str(args.checkpoint))}` ({cfg.architecture}, K = {cfg.num_inference_steps}, "
        f"horizon {cfg.horizon}, n_action_steps {cfg.n_action_steps}); {args.episodes} episodes per cell, "
        f"seeds {EVAL_SEED}-{EVAL_SEED + args.episodes - 1} in every cell; control at {fps:g} Hz; torch "
        "with 1 thread.",
    ]
    if measured_s is not None:
        lines.append(
            f"Measured delay: median `predict_action_chunk` time {measured_s * 1000:.1f} ms at batch 1 "
            f"-> d = {delay_steps(measured_s, fps)} steps (1-minute load average {load:.1f} on "
            f"{os.cpu_count()} CPUs when it was measured)."
        )
    lines += [
        "",
        table(rows),
        "",
        "d: control steps the simulator runs the previous chunk (or holds its last action) before the new "
        "chunk arrives; latency compensation on skips those d actions of the new chunk. Success: the env's "
        "is_success at the end of the episode. Mean length: env steps. RMS jerk: of the EEF position in "
        "observation.state, third finite difference times fps^3, root mean squared norm per episode, "
        "mean over episodes. Semantics: the docstring of eval/bench/delay.py.",
    ]
    if args.note:
        lines += ["", args.note]
    lines += ["", describe()]
    text = "\n".join(lines)
    print(text)
    write_result(args.out, f"delay_{spec.name}.md", text)


if __name__ == "__main__":
    main()
