"""Open-loop error of a trained policy on held-out expert demonstrations.

    python eval/open_loop.py outputs/ablate/ckpt/<cell> --task MugHanging --variant train
    python eval/open_loop.py outputs/train/<run>/checkpoints/last/pretrained_model --task Stack --variant D0
    python eval/open_loop.py <diffusion checkpoint> --task Coffee --variant D0 \
        --set noise_scheduler_type=DDIM --set num_inference_steps=100

The checkpoint is an ActionFlow policy (``eval/ablate.py --save`` or ``lerobot-train``) or any other LeRobot
policy saved by ``lerobot-train`` (Diffusion Policy...), which reads the demonstrations through its own saved
pre- and post-processors (normalisation) and is compared on the actions it returns (Diffusion Policy: its
``n_action_steps``, from the current frame on).

For every frame of ``--episodes`` expert episodes recorded from seeds ``--seed``, ``--seed + 1``, ... (never
the training seeds 0, 1, ...), the policy samples a chunk from the demonstration's own observation history
and it is compared with the demonstration's next actions: the median position
error of chunk steps 0, 3 and 7, the median rotation error of steps 7 and 15 (and how often step 15 is off by
over 20 degrees), the spread of the samples over ``--samples`` noise draws, and how often the gripper command
has the wrong sign.
Rows: all frames, the 12 frames before the expert first closes the gripper (the grasp), the carry (from the
grasp to 12 frames before the release, where MugHanging turns the mug) and the 12 before it opens it again
(a release). This separates a policy that cannot fit its data (large errors here) from one that
drifts in closed loop (small errors here, failures in ``eval/ablate.py``).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).parent))
from ablate import Batches, parse_value, record  # noqa: E402

from lerobot_actionflow import ActionFlowPolicy  # noqa: E402
from lerobot_actionflow.core import geometry  # noqa: E402

Predict = Callable[[dict], torch.Tensor]


def override(config, settings: dict[str, str]):
    """``config`` with evaluation-time fields replaced, as ``lerobot-eval --policy.FIELD=VALUE`` does (e.g.
    ``noise_scheduler_type=DDIM``, ``num_inference_steps=10``, ``clip_sample=false``); values are read as
    ``eval/ablate.py`` reads its overrides, and an unknown field, or a value of the wrong kind for a boolean
    or numeric field, is refused by name."""
    import dataclasses

    fields = {f.name for f in dataclasses.fields(config)}
    changes = {}
    for name, text in settings.items():
        if name not in fields:
            raise SystemExit(f"--set {name}={text}: {type(config).__name__} has no field {name!r}")
        value, current = parse_value(text), getattr(config, name)
        if isinstance(current, bool) and not isinstance(value, bool):
            raise SystemExit(f"--set {name}={text}: expected true or false")
        elif isinstance(current, int | float) and not isinstance(value, int | float):
            raise SystemExit(f"--set {name}={text}: expected a number")
        changes[name] = value
    return dataclasses.replace(config, **changes) if changes else config


def respace(policy, spacing: str) -> None:
    """Rebuild a Diffusion Policy's noise scheduler with diffusers' ``timestep_spacing`` (``leading``, the
    default: K steps from t = 100 - 100/K; ``trailing``: from t = 99, the noisiest; ``linspace``), its other
    settings kept. LeRobot's config has no such field; this tells a sampler's step count from where it
    starts."""
    scheduler = getattr(getattr(policy, "diffusion", None), "noise_scheduler", None)
    if scheduler is None:
        raise SystemExit(f"--timestep-spacing: a {type(policy).__name__} has no diffusion noise scheduler")
    policy.diffusion.noise_scheduler = type(scheduler).from_config(scheduler.config, timestep_spacing=spacing)


def load_policy(
    checkpoint: Path, settings: dict[str, str] | None = None, spacing: str | None = None
) -> tuple[int, int, Predict]:
    """``(n_obs_steps, horizon, predict)`` of a saved policy: ``predict(batch)`` maps raw demonstration
    observations ``{key: [B, n_obs, ...]}`` to a chunk of raw actions ``[B, H, 10]``, starting at the current
    frame. ActionFlow reads its raw token poses; another LeRobot policy goes through its saved processors.
    ``settings`` overrides config fields first (``override``), as lerobot-eval's ``--policy.*`` flags;
    ``spacing`` sets a diffusion sampler's timestep spacing (``respace``)."""
    from lerobot.configs.policies import PreTrainedConfig

    config = override(PreTrainedConfig.from_pretrained(checkpoint), settings or {})
    if config.type == "actionflow":
        if spacing is not None:
            raise SystemExit("--timestep-spacing: an ActionFlow policy has no diffusion noise scheduler")
        policy = ActionFlowPolicy.from_pretrained(checkpoint, config=config).eval()
        return policy.config.n_obs_steps, policy.config.horizon, policy.predict_action_chunk
    from lerobot.policies.factory import get_policy_class, make_pre_post_processors

    policy = get_policy_class(config.type).from_pretrained(checkpoint, config=config).eval()
    if spacing is not None:
        respace(policy, spacing)
    pre, post = make_pre_post_processors(policy.config, pretrained_path=str(checkpoint))
    keys = set(policy.config.input_features)

    def predict(batch: dict) -> torch.Tensor:
        missing = keys - set(batch)
        if missing:
            raise KeyError(f"the demonstrations lack {sorted(missing)}, which {checkpoint} reads")
        policy.reset()  # empty observation queues: predict_action_chunk reads the batch's own history
        return post(policy.predict_action_chunk(pre({k: batch[k] for k in keys})))

    return policy.config.n_obs_steps, policy.config.n_action_steps, predict


def phases(data: dict) -> dict[str, np.ndarray]:
    """Frame masks: all, the 12 frames before each episode's first close, the carry, the 12 before the next
    open."""
    grip, episode = data["action"][:, 9], data["episode"]
    grasp, carry, release = (np.zeros(len(grip), bool) for _ in range(3))
    for e in np.unique(episode):
        idx = np.where(episode == e)[0]
        g = grip[idx]
        close = int(np.argmax(g > 0))
        opened = close + int(np.argmax(g[close:] < 0)) if np.any(g[close:] < 0) else len(g)
        grasp[idx[max(close - 12, 0) : close]] = True
        carry[idx[close : max(opened - 12, close)]] = True
        release[idx[max(opened - 12, 0) : opened]] = True
    return {"all frames": np.ones(len(grip), bool), "12 before grasp": grasp, "carry": carry,
            "12 before release": release}


@torch.no_grad()
def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("checkpoint", type=Path)
    p.add_argument("--task", default="MugHanging")
    p.add_argument("--variant", default="train")
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--seed", type=int, default=5000, help="first demonstration seed (held out from training)")
    p.add_argument("--samples", type=int, default=4)
    p.add_argument("--cache", type=Path, default=Path("outputs/ablate/data"))
    p.add_argument("--env-kwarg", action="append", default=[], metavar="KEY=VALUE",
                   help="gym.make keyword of the demonstrations' env, e.g. mug_yaw=slight")
    p.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", dest="settings",
                   help="override a policy config field first, e.g. noise_scheduler_type=DDIM "
                   "num_inference_steps=10 (repeatable)")
    p.add_argument("--timestep-spacing", choices=("leading", "trailing", "linspace"),
                   help="Diffusion Policy only: where its K sampling steps sit among the 100 trained ones "
                   "(default: as saved, diffusers' leading)")
    args = p.parse_args(argv)

    torch.set_num_threads(1)
    bad = [kv for kv in args.settings if "=" not in kv]
    if bad:
        raise SystemExit(f"--set {bad[0]!r}: expected FIELD=VALUE")
    settings = dict(kv.split("=", 1) for kv in args.settings)
    n_obs, horizon, predict = load_policy(args.checkpoint, settings, args.timestep_spacing)
    if horizon < 8:
        raise SystemExit(f"{args.checkpoint} returns {horizon} actions per chunk; the table reads steps 0-7")
    env_kwargs = dict(kv.split("=", 1) for kv in args.env_kwarg)
    data = record(args.task, args.variant, args.episodes, 1.0, env_kwargs, args.cache, first_seed=args.seed)
    batches = Batches(data, n_obs, horizon)
    batch = batches.at(torch.arange(batches.size))
    demo = batch.pop("action")
    chunks = []
    for s in range(args.samples):
        torch.manual_seed(s)
        chunks.append(predict(batch))
    chunks = torch.stack(chunks)  # [S, n, H, 10]
    trans_err, rot_err = geometry.pose9_errors(chunks[0, ..., :9], demo[..., :9])  # [n, H] m, rad
    err = trans_err.numpy() * 1000  # mm
    spread = (chunks[..., :3] - chunks[..., :3].mean(0)).norm(dim=-1).mean(0).numpy() * 1000
    wrong = (chunks[0, ..., 9].sign() != demo[..., 9].sign()).numpy()
    rot_err = np.degrees(rot_err.numpy())
    print(f"{args.checkpoint}: {args.episodes} {args.task} {args.variant} demonstrations, seeds {args.seed}+")
    last = horizon - 1  # ActionFlow's chunk: step 15; Diffusion Policy's executed actions: step 7
    print(f"| frames | n | error step 0 / 3 / 7 (mm) | rotation error step 7 / {last} (deg) "
          f"| rotation step {last} > 20 deg | sample spread step 0 / 7 (mm) | gripper wrong 0-7 |")
    print("|---|---|---|---|---|---|---|")
    for name, mask in phases(data).items():
        e, sp, r = (np.median(x[mask], axis=0) for x in (err, spread, rot_err))
        far = (rot_err[mask, last] > 20).mean()
        print(f"| {name} | {mask.sum()} | {e[0]:.1f} / {e[3]:.1f} / {e[7]:.1f} | {r[7]:.1f} / {r[last]:.1f} "
              f"| {far:.1%} | {sp[0]:.1f} / {sp[7]:.1f} | {wrong[mask, :8].mean():.1%} |")


if __name__ == "__main__":
    main()
