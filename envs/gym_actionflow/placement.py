"""Initial-state samplers: object positions on the table drawn from ``env.np_random``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Region:
    """An axis-aligned xy rectangle on the table and a yaw interval (radians)."""

    x: tuple[float, float]
    y: tuple[float, float]
    yaw: tuple[float, float] = (0.0, 2 * np.pi)

    def sample(self, rng: np.random.Generator) -> tuple[np.ndarray, float]:
        xy = np.array([rng.uniform(*self.x), rng.uniform(*self.y)])
        return xy, float(rng.uniform(*self.yaw))


def square(half: float, center: tuple[float, float] = (0.0, 0.0), yaw=(0.0, 2 * np.pi)) -> Region:
    """A square region of half-width ``half`` metres around ``center``."""
    return Region((center[0] - half, center[0] + half), (center[1] - half, center[1] + half), tuple(yaw))


def sample_separated(
    rng: np.random.Generator,
    regions: list[Region],
    radii: list[float],
    fixed: list[tuple[np.ndarray, float]] = (),
    max_tries: int = 1000,
) -> list[tuple[np.ndarray, float]]:
    """One (xy, yaw) per region such that the discs of the given radii (and the ``fixed`` (xy, radius) discs)
    do not overlap. Rejection sampling, object by object, as robosuite's placement samplers do."""
    placed: list[tuple[np.ndarray, float]] = []
    discs = [(np.asarray(c, dtype=float), r) for c, r in fixed]
    for region, radius in zip(regions, radii, strict=True):
        for _ in range(max_tries):
            xy, yaw = region.sample(rng)
            if all(np.linalg.norm(xy - c) > radius + r for c, r in discs):
                break
        else:
            raise RuntimeError(
                f"could not place an object of radius {radius} in {region} after {max_tries} tries"
            )
        placed.append((xy, yaw))
        discs.append((xy, radius))
    return placed
