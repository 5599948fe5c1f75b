"""Discovery shim: LeRobot imports installed distributions named lerobot_policy_*; registers ActionFlow."""

import lerobot_actionflow  # noqa: F401
