"""Fast ablations of ActionFlow's settings on a gym_actionflow task: record, train, evaluate in one process.

    python eval/ablate.py --task MugHanging --variant train --episodes 50 --steps 3000 \
        --eval-variants train test --name base
    python eval/ablate.py ... --set n_action_steps=2 --set translation_scale=5 --name short_exec

It is the same policy, data and evaluation as ``actionflow-record`` -> ``lerobot-train`` -> ``lerobot-eval``
(same expert seeds and noise, LeRobot's history/chunk padding, AdamW with a cosine schedule and warm-up,
gradient clipping, the evaluation seeds of ``lerobot-eval --seed=100000``), without LeRobotDataset's
per-sample cost: the demonstrations are held as tensors and batches are cut from them directly, so a cell
of an ablation trains several times faster on a CPU. Every finished cell is appended to a JSON-lines
results file and skipped when the same command runs again (resumable).
"""

from __future__ import annotations

import argparse
import collections
import hashlib
import importlib
import inspect
import json
import math
import time
from pathlib import Path

import numpy as np
import torch
from gym_actionflow.tasks.lightbulb import SOCKET_TOP as LIGHTBULB_SOCKET_TOP
from tqdm import tqdm

from lerobot_actionflow import ActionFlowConfig, ActionFlowPolicy, make_actionflow_pre_post_processors, schema

RUNTIME_FIELDS = ("n_action_steps", "num_inference_steps", "time_schedule", "time_schedule_rate",
                  "action_smoothing")
"""Config fields read at every call, which an evaluation of a trained policy may change."""
STREAM_BUFFER = 1000
"""Shuffle buffer of LeRobot's ``StreamingLeRobotDataset`` (its default, which ``lerobot-train`` keeps)."""
EVAL_SEED = 100_000
"""First evaluation seed, as the main job's ``lerobot-eval --seed=100000``: never a recording seed."""


# ---------------------------------------------------------------------------- data
def make_env(task: str, variant: str, env_kwargs: dict):
    import gym_actionflow
    import gymnasium as gym

    spec = gym_actionflow.find_task(task)
    return spec, gym.make(spec.env_id, **spec.kwargs(variant), **env_kwargs)


def record(
    task: str, variant: str, episodes: int, noise: float, env_kwargs: dict, cache: Path, first_seed: int = 0
) -> dict:
    """Successful expert episodes from seeds ``first_seed``, +1, ... (as ``actionflow-record``), as
    ``{policy key: array}`` frames plus ``episode``; cached as an .npz keyed by the source of the task and its
    expert."""
    import gym_actionflow

    spec, env = make_env(task, variant, env_kwargs)
    modules = (e.split(":")[0] for e in (spec.entry_point, spec.expert))
    sources = [inspect.getsource(importlib.import_module(m)) for m in modules]
    digest = hashlib.sha1("".join(sources).encode()).hexdigest()[:8]
    tag = "".join(f"_{k}-{v}" for k, v in sorted(env_kwargs.items()))
    start = f"_from{first_seed}" if first_seed else ""
    path = cache / f"{spec.name}_{variant}_{episodes}_n{noise:g}{tag}{start}_{digest}.npz"
    if path.exists():
        env.close()
        return dict(np.load(path))
    frames: dict[str, list] = collections.defaultdict(list)
    seed, kept = first_seed, 0
    bar = tqdm(total=episodes, desc=f"recording {spec.name} {variant}")
    while kept < episodes:
        steps: list[tuple[dict, np.ndarray]] = []
        expert = gym_actionflow.make_expert(env, noise=noise, seed=seed)
        episode = gym_actionflow.run_episode(env, expert, seed, on_step=lambda o, a: steps.append((o, a)))  # noqa: B023
        seed += 1
        if not episode.success:
            continue
        for obs, action in steps:
            for key, value in schema.dataset_frame(obs, action, spec.name).items():
                if key.startswith(schema.IMAGES):
                    frames[key].append(np.asarray(value, dtype=np.uint8))  # (H, W, 3), as rendered
                elif key != "task":
                    frames[key].append(np.asarray(value, dtype=np.float32))
            frames["episode"].append(kept)
        kept += 1
        bar.update()
    bar.close()
    env.close()
    data = {k: np.stack(v) for k, v in frames.items()}
    cache.mkdir(parents=True, exist_ok=True)
    np.savez(path, **data)
    return data


class Batches:
    """Training samples with LeRobot's delta-timestamp semantics: an observation history of ``n_obs`` steps
    (indices before the episode start repeat its first frame) and ``horizon`` actions (indices past the end
    repeat the last action and are flagged in ``action_is_pad``). Camera images are held as the env rendered
    them, ``(H, W, 3)`` uint8 (a quarter of the memory of floats), and a batch gets them as LeRobot's loader
    gives them: ``(3, H, W)`` float in [0, 1]. They are the raw renders, not a video's decoded frames."""

    def __init__(self, data: dict, n_obs: int, horizon: int):
        self.tensors = {k: torch.from_numpy(v) for k, v in data.items() if k.startswith("observation.")}
        self.action = torch.from_numpy(data[schema.ACTION])
        episode = torch.from_numpy(data["episode"]).long()
        n = episode.numel()
        index = torch.arange(n)
        starts = torch.zeros(n, dtype=torch.long)
        ends = torch.zeros(n, dtype=torch.long)
        for e in episode.unique():
            mask = episode == e
            idx = index[mask]
            starts[mask], ends[mask] = idx.min(), idx.max()
        obs_off = torch.arange(1 - n_obs, 1)
        act_off = torch.arange(horizon)
        self.obs_idx = torch.maximum(index[:, None] + obs_off, starts[:, None])  # [n, T]
        raw = index[:, None] + act_off
        self.act_idx = torch.minimum(raw, ends[:, None])  # [n, H]
        self.act_pad = raw > ends[:, None]
        self.size = n

    def at(self, i: torch.Tensor) -> dict:
        """The training samples of frames ``i [B]``: observations ``[B, T, ...]``, actions ``[B, H, 10]``."""
        batch = {k: v[self.obs_idx[i]] for k, v in self.tensors.items()}
        for k in batch:
            if k.startswith(schema.IMAGES):
                batch[k] = batch[k].permute(0, 1, 4, 2, 3).float() / 255
        batch["action"] = self.action[self.act_idx[i]]
        batch["action_is_pad"] = self.act_pad[i]
        return batch

    def sample(self, batch_size: int, gen: torch.Generator) -> dict:
        """A batch of frames drawn uniformly with replacement."""
        return self.at(torch.randint(self.size, (batch_size,), generator=gen))


def stream_order(size: int, buffer_size: int, gen: torch.Generator):
    """Frame indices in the order LeRobot's ``StreamingLeRobotDataset`` yields one shard: frames are read in
    file order into a ``buffer_size`` buffer, and each read swaps out a uniformly chosen buffered frame; at
    the end of an epoch the rest of the buffer is shuffled. ``--loader stream`` trains on this order, to
    measure what the streaming loader's local shuffle costs against uniform sampling."""
    while True:
        buffer: list[int] = []
        for i in range(size):
            if len(buffer) == buffer_size:
                j = int(torch.randint(buffer_size, (1,), generator=gen))
                yield buffer[j]
                buffer[j] = i
            else:
                buffer.append(i)
        for j in torch.randperm(len(buffer), generator=gen).tolist():
            yield buffer[j]


# ---------------------------------------------------------------------------- policy
def make_policy(data: dict, overrides: dict) -> ActionFlowPolicy:
    """ActionFlow with its config defaults and ``overrides``, for the recorded observation keys."""
    cfg = ActionFlowConfig(device="cpu", **overrides)
    shapes = {k: tuple(v.shape[1:]) for k, v in data.items() if k.startswith("observation.")}
    env_shapes = {env_key: shapes[schema.policy_key(env_key)] for env_key in schema.FEATURES_MAP
                  if schema.policy_key(env_key) in shapes}
    cfg.input_features, cfg.output_features = schema.policy_features(env_shapes)
    return ActionFlowPolicy(cfg)


def save(policy: ActionFlowPolicy, path: Path) -> None:
    """Save ``policy`` as ``lerobot-train`` saves a checkpoint: weights and config, and the processor
    pipelines beside them (ActionFlow normalises nothing, so they need no dataset statistics), so that
    ``lerobot-eval --policy.path`` loads it."""
    policy.save_pretrained(path)
    for pipeline in make_actionflow_pre_post_processors(policy.config):
        pipeline.save_pretrained(path)


def lr_at(step: int, cfg: ActionFlowConfig, total: int) -> float:
    """LeRobot's cosine decay with linear warm-up (``CosineDecayWithWarmupSchedulerConfig``), decaying over
    the run as the main job sets ``scheduler_decay_steps`` to ``--steps``."""
    warm = cfg.scheduler_warmup_steps
    if step < warm:
        return cfg.optimizer_lr * (step + 1) / (warm + 1)
    progress = min((step - warm) / max(total - warm, 1), 1.0)
    cos = 0.5 * (1 + math.cos(math.pi * progress))
    return cfg.scheduler_decay_lr + (cfg.optimizer_lr - cfg.scheduler_decay_lr) * cos


def lerobot_batches(policy: ActionFlowPolicy, root: Path, batch_size: int):
    """Endless batches from LeRobot's own streaming loader over the LeRobotDataset at ``root``, built as
    ``lerobot-train --dataset.streaming=true --num_workers=1`` builds it (its delta timestamps, one worker,
    persistent, prefetch 4), for ``--loader lerobot``."""
    from lerobot.datasets import LeRobotDatasetMetadata, resolve_delta_timestamps
    from lerobot.datasets.streaming_dataset import StreamingLeRobotDataset

    meta = LeRobotDatasetMetadata("local/ablate", root=root)
    dataset = StreamingLeRobotDataset("local/ablate", root=root, max_num_shards=1,
                                      delta_timestamps=resolve_delta_timestamps(policy.config, meta))
    loader = torch.utils.data.DataLoader(dataset, batch_size=batch_size, num_workers=1, drop_last=False,
                                         persistent_workers=True, prefetch_factor=4)
    while True:
        yield from loader


def train(policy: ActionFlowPolicy, batches: Batches, steps: int, batch_size: int, seed: int,
          loader: str = "uniform", dataset_root: Path | None = None) -> list[float]:
    cfg = policy.config
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    opt = torch.optim.AdamW(policy.get_optim_params(), lr=cfg.optimizer_lr, betas=cfg.optimizer_betas,
                            eps=cfg.optimizer_eps, weight_decay=cfg.optimizer_weight_decay)
    policy.train()
    losses = []
    order = stream_order(batches.size, STREAM_BUFFER, gen) if loader == "stream" else None
    stream = lerobot_batches(policy, dataset_root, batch_size) if loader == "lerobot" else None
    bar = tqdm(range(steps), desc="training", mininterval=5)
    for step in bar:
        for group in opt.param_groups:
            group["lr"] = lr_at(step, cfg, steps)
        if stream is not None:
            batch = next(stream)
        elif order is not None:
            batch = batches.at(torch.tensor([next(order) for _ in range(batch_size)]))
        else:
            batch = batches.sample(batch_size, gen)
        loss, _ = policy.forward(batch)
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(policy.parameters(), cfg.optimizer_grad_clip_norm)
        opt.step()
        policy.update()  # as lerobot-train: the weights' moving average, when the config keeps one
        losses.append(loss.item())
        if step % 100 == 0:
            bar.set_postfix(loss=f"{np.mean(losses[-100:]):.3f}")
    policy.eval()
    return losses


# ---------------------------------------------------------------------------- evaluation
@torch.no_grad()
def evaluate(policy: ActionFlowPolicy, task: str, variant: str, episodes: int, env_kwargs: dict) -> dict:
    """Closed-loop success over seeds ``EVAL_SEED ...`` (the layouts ``lerobot-eval --seed=100000`` sees)."""
    _, env = make_env(task, variant, env_kwargs)
    successes, lengths = [], []
    outcomes = collections.defaultdict(int)
    deepest: dict[int, dict] = {}
    torch.manual_seed(EVAL_SEED)
    for i in tqdm(range(episodes), desc=f"evaluating {variant}", mininterval=5):
        obs, _ = env.reset(seed=EVAL_SEED + i)
        policy.reset()
        done, info, steps = False, {}, 0
        probe = Probe(env.unwrapped)
        while not done:
            action = policy.select_action(schema.policy_batch(obs))[0].numpy()
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
            steps += 1
            probe.update()
        successes.append(bool(info["is_success"]))
        outcome = probe.outcome(bool(info["is_success"]))
        outcomes[outcome] += 1
        lengths.append(steps)
        if (closest := probe.deepest()) is not None:
            deepest[EVAL_SEED + i] = {"outcome": outcome, **closest}
    env.close()
    result = {"success": float(np.mean(successes)), "n": episodes, "mean_steps": float(np.mean(lengths)),
              "outcomes": dict(outcomes),
              "failed_seeds": [EVAL_SEED + i for i, s in enumerate(successes) if not s]}
    if deepest:
        result["deepest"] = deepest
    return result


class Probe:
    """How a failed episode failed, for the tasks that expose the checks.

    MugHanging: the mug was never lifted, lifted but its handle never reached the peg, or on the peg but not
    left hanging. Lightbulb: the cap never came within 3 mm of the socket axis below the rim's top plus 5 mm
    (``never_aligned``), it did but was never seated (``jammed``: on the rim or a pin on the wall), or it was
    seated but not left locked (``seated_not_locked``: turned too little, too far, or lifted out again). For
    Lightbulb it also keeps where the cap got deepest while within 4 mm of the socket axis (:meth:`deepest`):
    how far off the axis and how many degrees off the entry slots it was then, which tells a bulb held at the
    wrong angle from one held off centre."""

    def __init__(self, env):
        self.env = env
        self.lifted = self.on_peg = False
        self.aligned = self.seated = False
        self.best: tuple[float, float, float] | None = None  # (cap height, radial offset, slot angle)

    def update(self) -> None:
        env = self.env
        if hasattr(env, "handle_on_peg"):
            self.lifted |= bool(env.body_pose(env.mug_id)[0][2] > 0.05)
            self.on_peg |= env.handle_on_peg()
        elif hasattr(env, "bulb_seated"):
            pos, _ = env.bulb_in_socket()
            radial = float(np.hypot(pos[0], pos[1]))
            self.aligned |= bool(radial < 0.003 and pos[2] < LIGHTBULB_SOCKET_TOP + 0.005)
            self.seated |= env.bulb_seated()
            if radial < 0.004 and (self.best is None or pos[2] < self.best[0]):
                self.best = (float(pos[2]), radial, env.bulb_angle())

    def deepest(self) -> dict | None:
        """Lightbulb: the cap's lowest point within 4 mm of the socket axis, as its height above the socket
        floor and its offset from the axis (mm) and the pins' angle from the entry slots (degrees, in
        [-90, 90): 0 is aligned, 67 locked); None for other tasks or if the cap never came that close."""
        if self.best is None:
            return None
        height, radial, angle = self.best
        return {"height_mm": round(height * 1e3, 2), "radial_mm": round(radial * 1e3, 2),
                "angle_deg": round(float(np.rad2deg(angle)), 1)}

    def outcome(self, success: bool) -> str:
        if success:
            return "success"
        if hasattr(self.env, "handle_on_peg"):
            if self.on_peg:
                return "on_peg_not_hung"
            return "lifted_missed_peg" if self.lifted else "never_lifted"
        if hasattr(self.env, "bulb_seated"):
            return "seated_not_locked" if self.seated else "jammed" if self.aligned else "never_aligned"
        return "failure"


def table(results: Path) -> str:
    """A results file as a Markdown table: one row per cell, success per evaluated variant with its count."""
    rows = [json.loads(line) for line in results.read_text().splitlines() if line.strip()]
    variants = list(dict.fromkeys(v for r in rows for v in r["eval"]))
    head = ["cell", "demos", "steps", "settings", "train s"] + [f"{v} success" for v in variants]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        parts = [f"{k}={v}" for k, v in r["overrides"].items()]
        settings = ", ".join(parts + [f"env {k}={v}" for k, v in r["env_kwargs"].items()]) or "defaults"
        if r.get("checkpoint"):
            settings += f" (evaluating {Path(r['checkpoint']).name})"
        if r.get("note"):
            settings += f"; {r['note']}"
        trained = [str(r["episodes"]), str(r["steps"])] if not r.get("checkpoint") else ["", ""]
        cells = [r["name"], *trained, settings, f"{r['train_s']:.0f}" if not r.get("checkpoint") else ""]
        for v in variants:
            e = r["eval"].get(v)
            cells.append(f"{e['success']:.0%} of {e['n']}" if e else "")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines + deepest_table(rows))


def deepest_table(rows: list[dict]) -> list[str]:
    """Lightbulb cells that kept :meth:`Probe.deepest`: per cell and outcome, the episodes that came within
    4 mm of the socket axis and the medians of where the cap got deepest."""
    lines = []
    for r in rows:
        for variant, e in r["eval"].items():
            by_outcome: dict[str, list[dict]] = collections.defaultdict(list)
            for d in e.get("deepest", {}).values():
                by_outcome[d["outcome"]].append(d)
            for outcome, ds in sorted(by_outcome.items()):
                med = {k: float(np.median([abs(d[k]) for d in ds]))
                       for k in ("height_mm", "radial_mm", "angle_deg")}
                lines.append(f"| {r['name']} | {variant} | {outcome} | {len(ds)} of {e['n']} | "
                             f"{med['height_mm']:.1f} | {med['radial_mm']:.2f} | {med['angle_deg']:.1f} |")
    if not lines:
        return []
    head = ("\n| cell | layouts | outcome | came within 4 mm | cap height above the floor (mm) "
            "| off the axis (mm) | off the entry slots (degrees) |")
    return [head, "|---|---|---|---|---|---|---|", *lines]


def parse_value(text: str):
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return {"true": True, "false": False}.get(text.lower(), text)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--task", default="MugHanging")
    p.add_argument("--variant", default="train")
    p.add_argument("--episodes", type=int, default=50)
    p.add_argument("--noise", type=float, default=1.0)
    p.add_argument("--steps", type=int, default=3000)
    p.add_argument("--batch-size", type=int, default=32)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--init-seed", type=int, default=None,
                   help="seed torch before the policy is built, for reproducible initial weights (default: "
                   "unseeded, as the cells before this option)")
    p.add_argument("--loader", choices=("uniform", "stream", "lerobot"), default="uniform",
                   help="uniform: frames drawn with replacement (a map-style loader's shuffle); stream: the "
                   "order of LeRobot's streaming dataset over one file (a 1000-frame shuffle buffer); "
                   "lerobot: LeRobot's streaming loader itself over --dataset-root")
    p.add_argument("--dataset-root", type=Path, default=None,
                   help="with --loader lerobot: a LeRobotDataset of the same demonstrations "
                   "(actionflow-record)")
    p.add_argument("--eval-variants", nargs="+", default=None)
    p.add_argument("--eval-episodes", type=int, default=50)
    p.add_argument("--env-kwarg", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE",
                   help="ActionFlowConfig override, e.g. --set n_action_steps=2")
    p.add_argument("--name", default=None, help="cell name in the results file (default: the overrides)")
    p.add_argument("--results", type=Path, default=None)
    p.add_argument("--cache", type=Path, default=Path("outputs/ablate/data"))
    p.add_argument("--save", type=Path, default=None, help="save the trained policy here")
    p.add_argument("--checkpoint", type=Path, default=None,
                   help="evaluate this saved policy instead of training one; --set may then change only the "
                   f"runtime fields {RUNTIME_FIELDS}")
    p.add_argument("--table", type=Path, default=None, help="print a results file as Markdown and exit")
    args = p.parse_args(argv)
    if args.table:
        print(table(args.table))
        return

    overrides = dict(s.split("=", 1) for s in args.set)
    overrides = {k: parse_value(v) for k, v in overrides.items()}
    env_kwargs = {k: parse_value(v) for k, v in (s.split("=", 1) for s in args.env_kwarg)}
    name = args.name or (",".join(f"{k}={v}" for k, v in overrides.items()) or "default")
    results = args.results or Path(f"eval/results/ablate_{args.task}.jsonl")
    key = dict(name=name, task=args.task, variant=args.variant, episodes=args.episodes, steps=args.steps,
               batch_size=args.batch_size, seed=args.seed, overrides=overrides, env_kwargs=env_kwargs,
               checkpoint=str(args.checkpoint) if args.checkpoint else None, loader=args.loader,
               init_seed=args.init_seed)
    if results.exists():
        for line in results.read_text().splitlines():
            row = json.loads(line)
            if {k: row.get(k, "uniform" if k == "loader" else None) for k in key} == key:
                print(f"already done: {json.dumps(row)}")
                return

    torch.set_num_threads(1)
    if args.checkpoint is not None:
        unknown = sorted(set(overrides) - set(RUNTIME_FIELDS))
        if unknown:
            raise ValueError(
                f"--set {unknown} with --checkpoint; a trained policy can change only {RUNTIME_FIELDS}"
            )
        policy = ActionFlowPolicy.from_pretrained(args.checkpoint)
        for field, value in overrides.items():
            setattr(policy.config, field, value)
        frames, train_s, final_loss = None, 0.0, None
    else:
        data = record(args.task, args.variant, args.episodes, args.noise, env_kwargs, args.cache)
        if args.init_seed is not None:
            torch.manual_seed(args.init_seed)
        policy = make_policy(data, overrides)
        batches = Batches(data, policy.config.n_obs_steps, policy.config.horizon)
        t0 = time.time()
        if args.loader == "lerobot" and args.dataset_root is None:
            raise ValueError("--loader lerobot needs --dataset-root (a LeRobotDataset of the demonstrations)")
        losses = train(policy, batches, args.steps, args.batch_size, args.seed, args.loader,
                       args.dataset_root)
        train_s = time.time() - t0
        frames, final_loss = batches.size, float(np.mean(losses[-200:]))
        if args.save:
            save(policy, args.save)
    evals = {}
    for variant in args.eval_variants or [args.variant]:
        evals[variant] = evaluate(policy, args.task, variant, args.eval_episodes, env_kwargs)
        print(f"{name}: {variant} success {evals[variant]['success']:.0%}")
    row = {**key, "frames": frames, "train_s": round(train_s, 1), "final_loss": final_loss, "eval": evals,
           "command": "python eval/ablate.py " + " ".join(argv or __import__("sys").argv[1:])}
    results.parent.mkdir(parents=True, exist_ok=True)
    with results.open("a") as f:
        f.write(json.dumps(row) + "\n")
    print(json.dumps(row))


if __name__ == "__main__":
    main()
