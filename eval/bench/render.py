"""Offscreen rendering benchmark: what the cameras cost a gym_actionflow env.

    python -m eval.bench.render [--task Stack] [--renders 300] [--steps 400] [--out eval/results]

Two tables, both in one process on one core (MuJoCo renders on the CPU here, through Mesa's llvmpipe):

* renders per second of one camera (``front``, static, and ``wrist``, on the hand) at 80x80, the size of the
  LeRobot-layout recipes, and at 240x320, ``render()``'s size, for reference: ``--renders`` calls of the
  env's own renderer (scene update + render + copy), after a warm-up, with the GL backend MuJoCo uses
  (``MUJOCO_GL``: egl or osmesa; the table names it and the GL renderer); plus the front camera at 80x80 with
  the robot's visual meshes hidden, which shows what the triangles cost;
* env steps per second on ``--task`` with ``obs_mode="state"``, ``"pixels"`` with the wrist camera (the
  default), and ``"pixels"`` with both cameras (``cameras=("front", "wrist")``) in the token and the LeRobot
  layout, 80x80 images: expert rollouts (noise 1, seeds from 0) of ``--steps`` steps, only ``env.step`` timed.

Prints the tables and writes them to ``<out>/render_cpu.md`` (default out: ``outputs/bench``).
"""

from __future__ import annotations

import argparse
import datetime
import functools
import os
import shlex
import sys
import time

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import gym_actionflow  # noqa: E402
import gymnasium as gym  # noqa: E402
import mujoco  # noqa: E402

from eval.bench.output import add_out_argument, write_result  # noqa: E402
from eval.provenance import describe  # noqa: E402

SIZES = ((80, 80), (240, 320))
"""(height, width) of the timed renders: the LeRobot-layout recipes' images, and render()'s frame."""
IMAGE_SIZE = 80
OBSERVATIONS: tuple[tuple[str, dict], ...] = (
    ("state (no camera)", {"obs_mode": "state"}),
    ("pixels: wrist (tokens)", {"obs_mode": "pixels"}),
    ("pixels: front + wrist (tokens)", {"obs_mode": "pixels", "cameras": ("front", "wrist")}),
    (
        "pixels: front + wrist (lerobot)",
        {"obs_mode": "pixels", "cameras": ("front", "wrist"), "obs_layout": "lerobot"},
    ),
)
"""The observations whose env steps are timed: (label, gym.make keywords)."""
ROBOT_MESH_GROUP = 2
"""The geom group of the robot's visual meshes (gym_actionflow.robot.add_panda)."""


def gl_renderer() -> str:
    """The GL implementation of the current context (``llvmpipe (LLVM 15.0.6, 256 bits)`` for Mesa on the
    CPU), or ``unknown`` where PyOpenGL cannot tell."""
    try:
        from OpenGL import GL

        return GL.glGetString(GL.GL_RENDERER).decode()
    except Exception:  # no current context, or a platform PyOpenGL does not know
        return "unknown"


def _seconds_per_call(call, calls: int) -> float:
    for _ in range(20):  # warm-up
        call()
    start = time.perf_counter()
    for _ in range(calls):
        call()
    return (time.perf_counter() - start) / calls


def time_renders(task: str, renders: int) -> tuple[list[tuple[str, str, float]], str, int]:
    """([(camera, size, seconds per render)], GL renderer, triangles of the model's meshes): the env's own
    renderer, and last the front camera at 80x80 without the robot's visual meshes."""
    env = gym.make(gym_actionflow.find_task(task).env_id)
    env.reset(seed=0)
    base = env.unwrapped
    rows = []
    for height, width in SIZES:
        for camera in ("front", "wrist"):
            name = base.camera_names[camera]
            render = functools.partial(base._render_camera, name, height, width)
            rows.append((camera, f"{height}x{width}", _seconds_per_call(render, renders)))
    renderer = gl_renderer()
    hidden = mujoco.MjvOption()
    hidden.geomgroup[ROBOT_MESH_GROUP] = 0
    gl = base._renderer(*SIZES[0])

    def render_without_robot_meshes() -> None:
        gl.update_scene(base.data, camera=base.camera_names["front"], scene_option=hidden)
        gl.render()

    rows.append(
        ("front, robot meshes hidden", "80x80", _seconds_per_call(render_without_robot_meshes, renders))
    )
    triangles = int(base.model.nmeshface)
    env.close()
    return rows, renderer, triangles


def time_steps(task: str, kwargs: dict, steps: int) -> float:
    """Mean seconds per ``env.step`` over expert rollouts of ``steps`` steps in all (seeds 0, 1, ...)."""
    spec = gym_actionflow.find_task(task)
    env = gym.make(spec.env_id, **spec.kwargs(), image_size=IMAGE_SIZE, **kwargs)
    total, count, seed = 0.0, 0, 0
    while count < steps:
        obs, _ = env.reset(seed=seed)
        expert = gym_actionflow.make_expert(env, noise=1.0, seed=seed)
        seed += 1
        while count < steps:
            action = expert.act(obs)
            start = time.perf_counter()
            obs, _, terminated, truncated, _ = env.step(action)
            total += time.perf_counter() - start
            count += 1
            if terminated or truncated:
                break
    env.close()
    return total / count


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--task", default="Stack", help="the task rendered and stepped (default Stack)")
    parser.add_argument("--renders", type=int, default=300, help="timed renders per camera and size")
    parser.add_argument("--steps", type=int, default=400, help="timed env steps per observation")
    add_out_argument(parser)
    args = parser.parse_args(argv)
    try:
        gym_actionflow.find_task(args.task)
    except ValueError as err:
        parser.error(str(err))

    render_rows, renderer, triangles = time_renders(args.task, args.renders)
    step_rows = [(label, time_steps(args.task, kwargs, args.steps)) for label, kwargs in OBSERVATIONS]
    state_s = step_rows[0][1]
    command = shlex.join(["python", "-m", "eval.bench.render", *(argv if argv is not None else sys.argv[1:])])
    lines = [
        "# Rendering benchmark (CPU)",
        "",
        f"`OMP_NUM_THREADS=1 {command}` on {datetime.date.today().isoformat()}, this project's 2-core CPU "
        "(shared with other work); one process. GL backend: "
        f"`MUJOCO_GL={os.environ['MUJOCO_GL']}`, renderer {renderer}.",
        "",
        f"One camera of {args.task}, the env's own renderer (scene update + render + copy), {args.renders} "
        "renders after 20 warm-up ones:",
        "",
        "| camera | image (H x W) | ms / render | renders / s |",
        "|---|---|---|---|",
        *(f"| {cam} | {size} | {1000 * s:.2f} | {1 / s:.0f} |" for cam, size, s in render_rows),
        "",
        f"The scene's meshes have {triangles:,} triangles, almost all of them the Panda's visual meshes: "
        "Mesa's llvmpipe processes every one on the CPU for each image, whatever its size, which is why an "
        "80x80 image costs nearly as much as a 240x320 one, and what hiding the robot's meshes saves.",
        "",
        f"{args.task} env steps with each observation ({IMAGE_SIZE}x{IMAGE_SIZE} images), expert rollouts of "
        f"{args.steps} steps, only `env.step` timed (physics, IK, observation, rendering):",
        "",
        "| observation | steps / s | ms / step | ms / step over state |",
        "|---|---|---|---|",
        *(
            f"| {label} | {1 / s:.0f} | {1000 * s:.2f} | {1000 * (s - state_s):+.2f} |"
            for label, s in step_rows
        ),
        "",
        describe(),
    ]
    text = "\n".join(lines)
    print(text)
    write_result(args.out, "render_cpu.md", text)


if __name__ == "__main__":
    main()
