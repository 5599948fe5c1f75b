"""Expert episodes from consecutive seeds, simulated in this process or in worker processes, always delivered
in seed order: the recording is the same whatever the number of workers.

Simulation (MuJoCo and the scripted expert) is the part of a recording that parallelises; writing the
dataset stays in the recording process. Workers never fork the recording process (MuJoCo's renderer and torch
do not survive a fork): they come from a fork server (:func:`_worker_context`), each with its own env and
offscreen renderer, and they exit on their own if the recording process is killed. As with any
``multiprocessing`` program, a script calling :func:`~.recorder.record` with workers needs an
``if __name__ == "__main__":`` guard.
"""

from __future__ import annotations

import itertools
import multiprocessing
import os
import signal
import threading
from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lerobot_actionflow import schema
from lerobot_actionflow.tools.record.recipe import Recipe

LOOKAHEAD = 2
"""Seeds handed out per worker ahead of the one the recording waits for: no worker idles while it writes."""


@dataclass
class Episode:
    """One expert episode of a recipe, as dataset columns."""

    seed: int
    success: bool
    columns: dict[str, np.ndarray]
    """Dataset key -> ``[T, *shape]``: :func:`schema.dataset_frame`'s frames, stacked (empty on failure)."""
    task: str
    """The task description stored with every frame."""
    segments: list[int] | None = None
    """A generated episode's source episode per subtask segment (None: not generated)."""

    def frames(self) -> Iterator[dict]:
        """The ``LeRobotDataset.add_frame`` frames, one per step."""
        length = len(next(iter(self.columns.values()))) if self.columns else 0
        for i in range(length):
            yield {key: column[i] for key, column in self.columns.items()} | {"task": self.task}


def make_env(recipe: Recipe):
    """The env a recipe records (``gym.make`` with its task, variant, observation mode, layout and cameras,
    and extra keywords)."""
    import gymnasium as gym
    from gym_actionflow import find_task

    task = find_task(recipe.task)
    kwargs = task.kwargs(recipe.variant, recipe.obs_mode, recipe.obs_layout, recipe.cameras)
    try:
        return gym.make(task.env_id, **kwargs, **recipe.env_kwargs)
    except TypeError as err:  # a keyword the env does not take, past the recipe's check of its signature
        if not recipe.env_kwargs:
            raise
        raise ValueError(f"env_kwargs {recipe.env_kwargs}: not accepted by {task.env_id}: {err}") from None


def simulate(env, recipe: Recipe, seed: int) -> Episode:
    """Run the recipe's expert (or, with a ``source``, a generated episode) on ``env`` from ``seed``; the
    episode is a function of the seed alone."""
    from gym_actionflow import make_expert, run_episode

    task = env.unwrapped.task_description
    frames: list[dict] = []
    segments = None

    def keep(obs: dict, action: np.ndarray) -> None:
        frames.append(schema.dataset_frame(obs, action, task))

    if recipe.source is not None:  # generated from a source dataset's segments (actionflow-generate)
        from lerobot_actionflow.tools.generate import cached_source, run_generated

        source = cached_source(recipe.source, recipe.task)
        success, segments = run_generated(env, source, seed, recipe.noise, on_step=keep)
    elif recipe.policy is not None:  # a trained policy's rollout (actionflow-record --policy)
        from gym_actionflow.rollout import rollout

        act = policy_actor(recipe.policy, seed)
        success = rollout(env, act, seed, on_step=keep).success
    else:
        expert = make_expert(env, noise=recipe.noise, seed=seed)
        success = run_episode(env, expert, seed, on_step=keep).success
    if not success:
        return Episode(seed, False, {}, task)
    columns = {key: np.stack([frame[key] for frame in frames]) for key in frames[0] if key != "task"}
    return Episode(seed, True, columns, task, segments)


_policies: dict[str, tuple] = {}
"""Loaded policies by checkpoint path, one load per process (the recording's, or each worker's)."""


def policy_actor(checkpoint: str, seed: int):
    """``act(obs) -> action`` of the trained policy at ``checkpoint`` for one episode: its state reset, torch
    seeded with the episode's seed (so a rollout is a function of its seed), the observation through the
    policy's saved processors (ActionFlow's defaults where a checkpoint has none: its normalisation is the
    identity)."""
    import torch
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    from lerobot_actionflow import schema

    if checkpoint not in _policies:
        config = PreTrainedConfig.from_pretrained(checkpoint)
        policy = get_policy_class(config.type).from_pretrained(checkpoint, config=config).eval()
        saved = (Path(checkpoint) / "policy_preprocessor.json").is_file()
        if not saved and config.type != "actionflow":
            raise ValueError(f"--policy {checkpoint}: no saved processors (policy_preprocessor.json)")
        kwargs = {"pretrained_path": checkpoint} if saved else {}
        _policies[checkpoint] = (policy, *make_pre_post_processors(policy.config, **kwargs))
    policy, pre, post = _policies[checkpoint]
    policy.reset()
    torch.manual_seed(seed)

    def act(obs: dict) -> np.ndarray:
        with torch.inference_mode():
            action = post(policy.select_action(pre(schema.policy_batch(obs))))
        return action[0].cpu().numpy().astype(np.float32)

    return act


EXECUTORS = ("local", "ray")
"""Where episodes are simulated: ``local``, this process or a pool of worker processes on this machine;
``ray``, Ray actors on this machine or on a cluster (the ``ray`` extra)."""


def episodes(
    recipe: Recipe,
    first_seed: int,
    workers: int,
    env=None,
    executor: str = "local",
    address: str | None = None,
) -> Iterator[Episode]:
    """Episodes from seeds ``first_seed, first_seed + 1, ...`` in that order, endlessly.

    ``workers == 1`` simulates here on ``env``; more runs a pool of that many worker processes, with up to
    :data:`LOOKAHEAD` seeds per worker in flight. Closing the generator (or an exception in it) stops the
    workers after the episodes under way; those are dropped, and their seeds are tried again by the next run.
    ``executor="ray"`` simulates in ``workers`` Ray actors instead (:func:`_ray_episodes`).
    """
    if executor == "ray":
        yield from _ray_episodes(recipe, first_seed, workers, address)
        return
    if executor != "local":
        raise ValueError(f"executor={executor!r}; expected one of {EXECUTORS}")
    seeds = itertools.count(first_seed)
    if workers == 1:
        if env is None:
            raise ValueError("episodes(workers=1) simulates in this process: pass the env to simulate on")
        for seed in seeds:
            yield simulate(env, recipe, seed)
        return
    pool = ProcessPoolExecutor(
        workers,
        mp_context=_worker_context(),
        initializer=_start_worker,
        initargs=(recipe,),
    )
    try:
        in_flight: deque[Future] = deque()
        while True:
            while len(in_flight) < LOOKAHEAD * workers:
                in_flight.append(pool.submit(_simulate_in_worker, next(seeds)))
            yield in_flight.popleft().result()  # a worker that dies (e.g. out of memory) raises here
    finally:
        pool.shutdown(wait=True, cancel_futures=True)  # episodes under way finish, queued ones never start


def _worker_context() -> multiprocessing.context.BaseContext:
    """Workers forked from a fork server that has imported this module (and the main one) once: they start
    without paying the imports each (seconds: the package imports torch and LeRobot), and without inheriting
    anything MuJoCo or torch started in the recording process. Spawned where there is no fork server."""
    if "forkserver" not in multiprocessing.get_all_start_methods():
        return multiprocessing.get_context("spawn")
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(["__main__", __name__])
    return context


_worker: dict = {}
"""A worker process's recipe, and its env once the first seed arrives."""


def _start_worker(recipe: Recipe) -> None:
    # Ctrl-C in a terminal reaches every process of the group: the recording process handles it and stops the
    # pool, so a worker must not die of it half-way through an episode first.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_exit_with_parent, daemon=True).start()
    _worker["recipe"] = recipe


def _exit_with_parent() -> None:
    """A recording process killed by SIGKILL cannot stop its workers: they notice and exit (else they would
    keep the fork server alive, and with it the recording's stdout). The sentinel ``multiprocessing`` gives a
    child is closed when its parent exits, even while the parent is not yet reaped."""
    parent = multiprocessing.parent_process()
    if parent is not None:
        parent.join()
        os._exit(1)


def _simulate_in_worker(seed: int) -> Episode:
    if "env" not in _worker:  # made here, not in the initializer: an env error reaches the recording process
        _worker["env"] = make_env(_worker["recipe"])
    return simulate(_worker["env"], _worker["recipe"], seed)


# ---------------------------------------------------------------------------- Ray
class _Simulator:
    """A Ray actor: one env, the recipe's episodes for the seeds it is given (in the order given)."""

    def __init__(self, recipe: Recipe, source=None):
        if source is not None:  # the driver read and cut the source: no node needs the source's files
            from lerobot_actionflow.tools import generate

            generate.remember_source(recipe.source, recipe.task, source)
        self.recipe = recipe
        self.env = make_env(recipe)

    def simulate(self, seed: int) -> Episode:
        return simulate(self.env, self.recipe, seed)


def _ray_episodes(recipe: Recipe, first_seed: int, workers: int, address: str | None) -> Iterator[Episode]:
    """:func:`episodes` on ``workers`` Ray actors of one CPU each: on a Ray started here (``address`` None,
    with as many CPUs as workers) or on the cluster at ``address``. Seed ``first_seed + i`` goes to actor
    ``i % workers`` and the episodes come back in seed order, so the recording is the one a local run makes.
    A generation's source is read here and shipped to the actors; a ``--policy`` checkpoint must be at the
    same path on every node."""
    import logging

    try:
        import ray
    except ImportError:
        raise ImportError(
            "executor 'ray' needs Ray: pip install 'lerobot_policy_actionflow[ray]' (or pip install ray)"
        ) from None
    started_here = not ray.is_initialized()
    if started_here:
        local = {"num_cpus": workers} if address is None else {}
        ray.init(address=address, include_dashboard=False, log_to_driver=False, logging_level=logging.WARNING,
                 **local)  # fmt: skip
    actors = []
    try:
        source = None
        if recipe.source is not None:
            from lerobot_actionflow.tools.generate import cached_source

            source = cached_source(recipe.source, recipe.task)
        actor_class = ray.remote(num_cpus=1)(_Simulator)
        actors = [actor_class.remote(recipe, source) for _ in range(workers)]
        seeds = itertools.count(first_seed)
        in_flight: deque = deque()
        while True:
            while len(in_flight) < LOOKAHEAD * workers:
                seed = next(seeds)
                in_flight.append(actors[(seed - first_seed) % workers].simulate.remote(seed))
            yield ray.get(in_flight.popleft())  # an actor's error (its env, its episode) is raised here
    finally:
        for actor in actors:
            ray.kill(actor)
        if started_here:
            ray.shutdown()
