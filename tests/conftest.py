"""Offscreen rendering for the env tests: MuJoCo chooses its GL backend when it is first imported."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")
