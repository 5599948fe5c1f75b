"""gym_actionflow benchmark: env steps/s (state only and with the wrist camera), scripted-expert success and
how far objects sink under adversarial actions.

    python -m eval.bench.envs [--episodes 100] [--tasks StackThree Coffee] [--noise 0 1] [--workers 2]
                              [--out eval/results]

Speed: single process, one core (MuJoCo is single-threaded), expert rollouts, only ``env.step`` timed.
Success: ``--episodes`` seeded episodes (seeds 0..N-1) per task x variant x expert noise, in ``--workers``
processes. Penetration: the deepest object-table / object-object contact over ``--adversarial-seeds`` runs of
300 adversarial steps (random poses, huge values, the hand pressed down on every object; see
gym_actionflow.adversarial), and of objects at rest after a reset. Prints the tables and writes them to
``<out>/envs_cpu.md`` (default out: ``outputs/bench``).
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from concurrent.futures import ProcessPoolExecutor

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import gym_actionflow  # noqa: E402
import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
from gym_actionflow.adversarial import resting_penetration, run_adversarial  # noqa: E402
from gym_actionflow.experts.base import top_down  # noqa: E402
from gym_actionflow.geometry import pose9, rotation_angle  # noqa: E402
from tqdm import tqdm  # noqa: E402

from eval.bench.output import add_out_argument, write_result  # noqa: E402
from eval.provenance import describe  # noqa: E402


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


def run_episodes(args: tuple[str, str, float, list[int]]) -> list[tuple[bool, int]]:
    """(success, length) of the expert's episode on each seed, all in one env.

    One env per call, not per episode: an env built per episode grew a worker by about 10 MB an episode
    (2.8 GB over a full run). Nothing leaked (``malloc_trim`` gave it all back): once the first model is
    freed, glibc raises its mmap threshold and serves the next models' large blocks from its heap, where the
    episodes' small allocations split them. A seeded reset gives a reused env the same episode as a fresh one
    (the same final state, bit for bit)."""
    env_id, variant, noise, seeds = args
    env = gym.make(env_id, **gym_actionflow.find_task(env_id).kwargs(variant))
    episodes = [
        gym_actionflow.run_episode(env, gym_actionflow.make_expert(env, noise=noise, seed=seed), seed)
        for seed in seeds
    ]
    env.close()
    return [(episode.success, episode.steps) for episode in episodes]


def tracking(env_id: str, controller: str) -> tuple[float, float, float]:
    """A robosuite task's control: (mean lag while the target circles 10 cm at up to 2.5 cm per step, error
    after settling for 2 s, worst wrist-turn error of turns up to 1.5 rad) in metres / metres / radians."""
    env = gym.make(env_id, controller=controller)
    obs, _ = env.reset(seed=0)
    base = env.unwrapped
    start, down = obs["token_poses"][0, :3].copy(), top_down(0.0)
    lag = []
    for k in range(100):
        target = start + np.array([0.1 * np.sin(k / 20), 0.1 * np.cos(k / 20) - 0.1, -0.1 * k / 100])
        obs, *_ = env.step(np.concatenate([pose9(target, down), [-1.0]]))
        lag.append(np.linalg.norm(obs["token_poses"][0, :3] - target))
    for _ in range(40):
        obs, *_ = env.step(np.concatenate([pose9(target, down), [-1.0]]))
    settled = float(np.linalg.norm(obs["token_poses"][0, :3] - target))
    turn = 0.0
    for yaw in (-1.5, -1.0, 1.0, 1.5):
        env.reset(seed=0)
        for _ in range(60):
            env.step(np.concatenate([pose9(start, top_down(yaw)), [-1.0]]))
        turn = max(turn, rotation_angle(base.tcp_pose()[1], top_down(yaw)))
    env.close()
    return float(np.mean(lag[5:])), settled, turn


def penetration(args: tuple[str, str, int]) -> tuple[float, float]:
    """(worst penetration under adversarial actions, worst at rest) in metres over seeds 0..seeds-1; NaN for
    the Robosuite* tasks, whose physics is robosuite's own."""
    env_id, variant, seeds = args
    if gym_actionflow.find_task(env_id).simulator != "mujoco":
        return float("nan"), float("nan")
    env = gym.make(env_id, **gym_actionflow.find_task(env_id).kwargs(variant)).unwrapped
    reports = [run_adversarial(env, seed=seed, steps=300) for seed in range(seeds)]
    bad = [r for r in reports if not r.finite or r.warnings]
    if bad:
        raise RuntimeError(f"{env_id} {variant}: adversarial actions broke the simulation: {bad}")
    rest = max(resting_penetration(env, seed=seed) for seed in range(seeds))
    env.close()
    return max(r.worst_penetration for r in reports), rest


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--episodes", type=int, default=100, help="seeded episodes per task x variant x noise"
    )
    parser.add_argument("--tasks", nargs="*", default=[t.name for t in gym_actionflow.TASKS])
    parser.add_argument("--noise", type=float, nargs="*", default=[0.0, 1.0], help="expert noise levels")
    parser.add_argument("--speed-steps", type=int, default=2000, help="timed env steps per task and obs mode")
    parser.add_argument(
        "--adversarial-seeds", type=int, default=10, help="adversarial runs (300 steps) per task x variant"
    )
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    add_out_argument(parser)
    args = parser.parse_args(argv)
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
    robosuite = [n for n in args.tasks if tasks[n].simulator == "robosuite"]
    track_rows = [(c, *tracking(tasks[robosuite[0]].env_id, c)) for c in ("ik", "osc")] if robosuite else []

    jobs = [
        (tasks[n].env_id, v, noise) for n in args.tasks for v in tasks[n].variants for noise in args.noise
    ]
    # One share of the seeds per worker (strided, so long and short episodes spread evenly).
    shares = [list(range(args.episodes))[k :: args.workers] for k in range(args.workers)]
    shares = [share for share in shares if share]
    success: dict[tuple[str, str], list[tuple[float, float]]] = {}
    # A fresh worker per task (one share of one cell): what glibc keeps of a cell's env is returned with its
    # process instead of piling up over the run (see run_episodes).
    with ProcessPoolExecutor(max_workers=args.workers, max_tasks_per_child=1) as pool:
        for env_id, variant, noise in tqdm(jobs, desc="experts"):
            parts = pool.map(run_episodes, [(env_id, variant, noise, share) for share in shares])
            results = [result for part in parts for result in part]
            ok = [r[0] for r in results]
            lengths = [r[1] for r in results]
            success.setdefault((env_id, variant), []).append((np.mean(ok), np.mean(lengths)))
        cells = list(success)
        sinking = list(pool.map(penetration, [(env_id, v, args.adversarial_seeds) for env_id, v in cells]))
    success_rows = [
        (env_id.split("/")[1][:-3], variant, success[env_id, variant], adversarial, rest)
        for (env_id, variant), (adversarial, rest) in zip(cells, sinking, strict=True)
    ]
    noises = " | ".join(f"success (noise {z:g})" for z in args.noise)
    lengths = " | ".join(f"length (noise {z:g})" for z in args.noise)

    everything = args.tasks == [t.name for t in gym_actionflow.TASKS]
    tasks_arg = "" if everything else " --tasks " + " ".join(args.tasks)
    lines = [
        "# gym_actionflow benchmark (CPU)",
        "",
        f"`python -m eval.bench.envs --episodes {args.episodes}{tasks_arg}"
        f" --adversarial-seeds {args.adversarial_seeds} --workers {args.workers}` on "
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
        *(
            [
                f"Robosuite tasks' control ({robosuite[0]}): the 10-d pose action through our IK and "
                "robosuite's JOINT_POSITION controller (`controller=\"ik\"`, the default) or robosuite's "
                "absolute OSC_POSE (`controller=\"osc\"`):",
                "",
                "| controller | lag on a 10 cm circle, mm | error 2 s after it stops, mm "
                "| worst error after a wrist turn of up to 1.5 rad, rad |",
                "|---|---|---|---|",
                *(f"| {c} | {1000 * lag:.2f} | {1000 * st:.3f} | {tr:.3f} |" for c, lag, st, tr in
                  track_rows),
                "",
            ]
            if track_rows
            else []
        ),
        f"Scripted expert success and mean episode length over seeds 0..{args.episodes - 1}; deepest "
        f"object-table / object-object penetration over {args.adversarial_seeds} adversarial runs of 300 "
        f"steps (seeds 0..{args.adversarial_seeds - 1}) and at rest after those resets:",
        "",
        f"| task | variant | {noises} | {lengths} | penetration, adversarial (mm) | at rest (mm) |",
        "|---|---|" + "---|" * (2 * len(args.noise) + 2),
        *(
            f"| {n} | {v} | "
            + " | ".join(f"{100 * s:.0f} %" for s, _ in cols)
            + " | "
            + " | ".join(f"{ln:.0f}" for _, ln in cols)
            + (f" | {1000 * adv:.2f} | {1000 * rest:.3f} |" if np.isfinite(adv) else " | n/a | n/a |")
            for n, v, cols, adv, rest in success_rows
        ),
        "",
        describe(),
    ]
    text = "\n".join(lines)
    print(text)
    write_result(args.out, "envs_cpu.md", text)


if __name__ == "__main__":
    main()
