"""Where a MugHanging policy brings the mug's handle, against the scripted expert on the same layouts.

    python -m eval.diagnostics.mug_trace <pretrained_model> --variant test --seeds 100000 100011
    python -m eval.diagnostics.mug_trace <pretrained_model> --variant test --episodes 20 --path 100011

``<pretrained_model>`` is an ActionFlow checkpoint (``lerobot-train``'s ``checkpoints/last/pretrained_model``
folder). For each layout (``env.reset(seed)``), the expert (noise 0) and the policy each run one episode
(:func:`gym_actionflow.rollout.rollout`). Everything is read in the hanger's frame (x along the peg's heading
from the pole, y sideways, z up from the pole's foot), following the centre of the handle's opening:
- ``start``: where the mug stands before the grasp;
- ``lined up``: the first step, after the lift, at which the opening is within 1 cm of the peg's vertical
  plane (|y| < 1 cm), lifted: the expert gets there above its insertion start (5 cm beyond the peg's tip,
  ``APPROACH_START``, x = 0.15 m), a policy that carries the mug by a learned displacement instead of to
  that point arrives short of it or beyond;
- whether the episode succeeded.
``--path SEED`` also prints that layout's whole path (every 6th step) for both.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gym_actionflow
import gymnasium as gym
import numpy as np
import torch
from gym_actionflow.experts.mug_hanging import APPROACH
from gym_actionflow.rollout import rollout
from gym_actionflow.tasks.mug_hanging import HOLE_CENTER, PEG_DIRECTION, PEG_TIP

from lerobot_actionflow import ActionFlowPolicy, schema
from lerobot_actionflow.recipes import EVAL_SEED, refuse_held_out

APPROACH_START = PEG_TIP + APPROACH * PEG_DIRECTION
"""Where the expert starts the slide, in the hanger frame: the opening ``APPROACH`` beyond the peg's tip."""
LINED_UP = 0.01
"""|y| of the opening (m) that counts as lined up with the peg's vertical plane."""
LIFTED = 0.10
"""The opening this high (m, hanger frame) counts as lifted; it starts at about 0.04 m."""


def opening_in_hanger_frame(sim) -> np.ndarray:
    """(3,) the centre of the handle's opening in the hanger's frame."""
    pos, rot = sim.body_pose(sim.mug_id)
    h_pos, h_rot = sim.body_pose(sim.hanger_id)
    return (pos + rot @ HOLE_CENTER - h_pos) @ h_rot


def run(
    env, seed: int, policy: ActionFlowPolicy | None, max_steps: int, hand: list | None = None
) -> tuple[np.ndarray, bool]:
    """One episode by the expert (``policy=None``) or the policy: the opening's path (T, 3) and success.
    With ``hand``, each step appends (gripper command, whether the fingers hold the mug after it)."""
    sim = env.unwrapped
    expert = gym_actionflow.make_expert(env, noise=0.0, seed=seed) if policy is None else None
    if policy is not None:
        policy.reset()
        torch.manual_seed(seed)
    path: list[np.ndarray] = []
    grip: list[float] = []  # the gripper command of each step

    def act(obs: dict) -> np.ndarray:
        if expert is not None:
            return expert.act(obs)
        return policy.select_action(schema.policy_batch(obs))[0].numpy()

    def start(obs: dict, info: dict) -> None:
        if expert is not None:
            expert.reset()
        path.append(opening_in_hanger_frame(sim))

    def commanded(obs: dict, action: np.ndarray) -> None:
        grip.append(float(action[-1]))

    def moved(obs: dict, reward: float, terminated: bool, truncated: bool, info: dict) -> None:
        path.append(opening_in_hanger_frame(sim))
        if hand is not None:
            hand.append((grip[-1], bool(sim.mug_held())))

    episode = rollout(
        env, act, seed, on_reset=start, on_step=commanded, after_step=moved, max_steps=max_steps
    )
    return np.array(path), episode.success


def lined_up(path: np.ndarray) -> np.ndarray | None:
    """The opening's position at the first lifted step within ``LINED_UP`` of the peg's plane, or None."""
    hits = np.where((path[:, 2] > LIFTED) & (np.abs(path[:, 1]) < LINED_UP))[0]
    return path[hits[0]] if len(hits) else None


def fmt(p: np.ndarray | None) -> str:
    return "never" if p is None else f"({p[0]:+.3f}, {p[1]:+.3f}, {p[2]:+.3f})"


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint", type=Path)
    p.add_argument("--variant", default="test")
    p.add_argument("--seeds", type=int, nargs="+", default=None)
    p.add_argument("--episodes", type=int, default=10, help="without --seeds: seeds 100000, 100001, ...")
    p.add_argument("--mug-yaw", default="slight")
    p.add_argument("--max-steps", type=int, default=300)
    p.add_argument("--path", type=int, default=None,
                   help="print this seed's whole path, with the gripper command and whether the mug is held")
    p.add_argument("--every", type=int, default=6, help="with --path: print every N-th step")
    args = p.parse_args(argv)
    seeds = args.seeds or list(range(EVAL_SEED, EVAL_SEED + args.episodes))
    try:
        refuse_held_out(seeds, "--seeds")
    except ValueError as err:
        p.error(str(err))

    policy = ActionFlowPolicy.from_pretrained(args.checkpoint).eval()
    env = gym.make("gym_actionflow/MugHanging-v0", variant=args.variant, mug_yaw=args.mug_yaw)
    print(f"{args.checkpoint}, MugHanging {args.variant}: the handle's opening in the hanger frame (m); the "
          f"expert's insertion start is at x = {APPROACH_START[0]:.3f}\n")
    print("| seed | start | expert lined up | policy lined up | expert / policy |")
    print("|---|---|---|---|---|")
    short = []
    for seed in seeds:
        hands: dict[str, list] = {"expert": [], "policy": []}
        expert_path, expert_ok = run(env, seed, None, args.max_steps, hands["expert"])
        policy_path, policy_ok = run(env, seed, policy, args.max_steps, hands["policy"])
        e, q = lined_up(expert_path), lined_up(policy_path)
        if e is not None and q is not None:
            short.append((policy_ok, e[0] - q[0]))
        ok = "/".join("ok" if s else "fail" for s in (expert_ok, policy_ok))
        print(f"| {seed} | {fmt(expert_path[0])} | {fmt(e)} | {fmt(q)} | {ok} |")
        if seed == args.path:
            for name, path in (("expert", expert_path), ("policy", policy_path)):
                print(f"\n{name} path, every {args.every} steps (x, y, z; gripper command, mug held):")
                for t in range(0, len(path), args.every):
                    grip, held = hands[name][t - 1] if t else (float("nan"), False)
                    print(f"  {t:3d} {fmt(path[t])} {grip:+.2f} {'held' if held else '-'}")
            print()
    for ok in (True, False):
        gaps = [g for s, g in short if s == ok]
        if gaps:
            mean, median = np.mean(gaps) * 100, np.median(gaps) * 100
            which = "successes" if ok else "failures"
            print(f"\npolicy {which}: lined up {mean:+.1f} cm short of the expert along the peg "
                  f"(mean of {len(gaps)}; median {median:+.1f})")
    env.close()


if __name__ == "__main__":
    main()
