"""gym_actionflow benchmark: env steps/s (state only and with the wrist camera) and scripted-expert success.

    python eval/bench_envs.py [--episodes 100] [--tasks StackThree Coffee] [--noise 0 1] [--workers 2]

Speed: single process, one core (MuJoCo is single-threaded), expert rollouts, only ``env.step`` timed.
Success: ``--episodes`` seeded episodes (seeds 0..N-1) per task x variant x expert noise, in ``--workers``
processes. Prints the tables and writes them to eval/results/envs_cpu.md.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import gym_actionflow  # noqa: E402
import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

RESULTS = Path(__file__).parent / "results" / "envs_cpu.md"


def time_steps(env_id: str, obs_mode: str, steps: int) -> float:
    """Mean seconds per env.step over expert rollouts of ``steps`` steps in all."""
    env = gym.make(env_id, obs_mode=obs_mode)
    expert = gym_actionflow.make_expert(env, noise=1.0, seed=0)
    total, count, seed = 0.0, 0, 0
    while count < steps:
        obs, _ = env.reset(seed=seed)
        expert.reset()
        seed += 1
        while count < steps:
            action = expert.act(obs)
            t0 = time.perf_counter()
            obs, _, terminated, truncated, _ = env.step(action)
            total += time.perf_counter() - t0
            count += 1
            if terminated or truncated:
                break
    env.close()
    return total / count


def time_point_cloud(resets: int) -> list[tuple[str, float, float]]:
    """MugHanging with ``hanger_obs="point_cloud"``: (variant, mean reset s, mean cloud s) over ``resets``."""
    rows = []
    for variant in ("train", "test"):
        env = gym.make("gym_actionflow/MugHanging-v0", variant=variant, hanger_obs="point_cloud")
        env.reset(seed=0)  # the first reset also creates the depth renderer
        total = cloud = 0.0
        for seed in range(1, resets + 1):
            start = time.perf_counter()
            env.reset(seed=seed)
            total += time.perf_counter() - start
            cloud += env.unwrapped.cloud_seconds
        env.close()
        rows.append((variant, total / resets, cloud / resets))
    return rows


def run_episode(args: tuple[str, str, float, int]) -> tuple[bool, int]:
    env_id, variant, noise, seed = args
    env = gym.make(env_id, **gym_actionflow.find_task(env_id).kwargs(variant))
    episode = gym_actionflow.run_episode(env, gym_actionflow.make_expert(env, noise=noise, seed=seed), seed)
    env.close()
    return episode.success, episode.steps


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--episodes", type=int, default=100, help="seeded episodes per task x variant x noise"
    )
    parser.add_argument("--tasks", nargs="*", default=[t.name for t in gym_actionflow.TASKS])
    parser.add_argument("--noise", type=float, nargs="*", default=[0.0, 1.0], help="expert noise levels")
    parser.add_argument("--speed-steps", type=int, default=2000, help="timed env steps per task and obs mode")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args()
    try:
        tasks = {name: gym_actionflow.find_task(name) for name in args.tasks}
    except ValueError as err:
        parser.error(str(err))

    speed_rows = []
    for name in tqdm(args.tasks, desc="speed"):
        env_id = tasks[name].env_id
        state = time_steps(env_id, "state", args.speed_steps)
        pixels = time_steps(env_id, "pixels", max(args.speed_steps // 4, 100))
        size = gym.make(env_id).unwrapped.image_size
        speed_rows.append((name, 1.0 / state, 1.0 / pixels, 1000 * (pixels - state), size))
    cloud_rows = time_point_cloud(20) if "MugHanging" in args.tasks else []

    jobs = [
        (tasks[n].env_id, v, noise) for n in args.tasks for v in tasks[n].variants for noise in args.noise
    ]
    success_rows = []
    with ProcessPoolExecutor(max_workers=args.workers) as pool:
        for env_id, variant, noise in tqdm(jobs, desc="experts"):
            results = list(pool.map(run_episode, [(env_id, variant, noise, s) for s in range(args.episodes)]))
            ok = [r[0] for r in results]
            lengths = [r[1] for r in results]
            success_rows.append((env_id.split("/")[1][:-3], variant, noise, np.mean(ok), np.mean(lengths)))

    everything = args.tasks == [t.name for t in gym_actionflow.TASKS]
    tasks_arg = "" if everything else " --tasks " + " ".join(args.tasks)
    lines = [
        "# gym_actionflow benchmark (CPU)",
        "",
        f"`python eval/bench_envs.py --episodes {args.episodes}{tasks_arg}` on "
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores; speed in one process.",
        "",
        "| task | steps/s (state) | steps/s (state + wrist RGB) | wrist image | camera ms/step |",
        "|---|---|---|---|---|",
        *(f"| {n} | {s:.0f} | {p:.0f} | {sz}x{sz} | {ms:.1f} |" for n, s, p, ms, sz in speed_rows),
        "",
        *(
            [
                "MugHanging point-cloud observation (7 depth views, rendered once per reset), 20 resets:",
                "",
                "| variant | reset with point cloud, s | of which the point cloud, s |",
                "|---|---|---|",
                *(f"| {lay} | {r:.3f} | {c:.3f} |" for lay, r, c in cloud_rows),
                "",
            ]
            if cloud_rows
            else []
        ),
        f"Scripted expert success over seeds 0..{args.episodes - 1}:",
        "",
        "| task | variant | noise | success | mean episode length |",
        "|---|---|---|---|---|",
        *(f"| {n} | {v} | {z:g} | {100 * s:.0f} % | {ln:.0f} |" for n, v, z, s, ln in success_rows),
        "",
    ]
    text = "\n".join(lines)
    print(text)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(text)
    print(f"written to {args.output}")


if __name__ == "__main__":
    main()
