"""Chunk latency of camera policies beside the pose policy and LeRobot's Diffusion Policy, in one run.

    python -m eval.bench.camera_latency [--device cpu|cuda] [--calls 20] [--out eval/results]

Every row is one action chunk (horizon 16) for a batch of one, timed after warm-up on the same machine in the
same process, in an interleaved order (row after row, round after round), so that load from other jobs falls
on all rows alike:

* ``pose``: ActionFlow A.1 with pose tokens only (2 history steps x 6 tokens), K = 4 Euler steps;
* ``wrist cnn`` / ``wrist resnet18``: the Lightbulb wrist-camera policy's inputs (2 tokens: end effector and
  bulb, an 80x80 wrist image; ``image_encoder`` cnn / resnet18), K = 4;
* ``diffusion``: LeRobot's Diffusion Policy with the same 80x80 image and the state, its ResNet18 image
  encoder (GroupNorm, from scratch), with the UNet of the paper harness's ``cpu`` profile (``down_dims``
  64-128-256) sampled with DDIM at 10 steps and with its own 100-step DDPM sampler, and with LeRobot's
  default UNet (512-1024-2048) at DDIM 10 steps (its 100-step DDPM sampler takes about 100 s a chunk on
  this project's CPU and is left out).

Prints a table (median / p90 ms) and writes it to ``<out>/camera_latency_<device>.md`` (default out:
``outputs/bench``).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from collections.abc import Callable

import torch

from eval.bench.output import add_out_argument, write_result
from eval.paper import profiles
from eval.provenance import describe, portable_command
from lerobot_actionflow import ActionFlowConfig, ActionFlowPolicy, schema
from lerobot_actionflow.core import geometry as g

IMAGE = (80, 80, 3)
WRIST = f"{schema.IMAGES}.wrist"
CPU_UNET = tuple(json.loads(profiles.CPU_UNET[0].split("=", 1)[1]))
"""The Diffusion Policy UNet of the paper harness's ``cpu`` profile (``--policy.down_dims=[64,128,256]``)."""


def actionflow(device: str, n_tokens: int, n_features: int, encoder: str | None) -> Callable[[], None]:
    """One ActionFlow chunk (K = 4) as a call, with or without an 80x80 wrist image."""
    shapes = schema.token_shapes(n_tokens, n_features)
    if encoder is not None:
        shapes[f"{schema.PIXELS}/wrist"] = IMAGE
    cfg = ActionFlowConfig(device=device, num_inference_steps=4, image_encoder=encoder or "cnn")
    cfg.input_features, cfg.output_features = schema.policy_features(shapes)
    policy = ActionFlowPolicy(cfg).to(device).eval()
    rot = g.random_rotation((1, 2, n_tokens))
    obs = {
        schema.TOKEN_POSES: g.rt_to_pose9(rot, torch.randn(1, 2, n_tokens, 3) * 0.2).to(device),
        schema.TOKEN_FEATURES: torch.randn(1, 2, n_tokens, n_features, device=device),
    }
    if encoder is not None:
        obs[WRIST] = torch.rand(1, 2, 3, *IMAGE[:2], device=device)
    return lambda: policy.predict_action_chunk(obs)


def diffusion(
    device: str, scheduler: str, steps: int, down_dims: tuple[int, ...] | None = None
) -> Callable[[], None]:
    """One chunk of LeRobot's Diffusion Policy (ResNet18 image encoder with a spatial softmax, the 1-D UNet
    with ``down_dims``, LeRobot's default when None) on the state and the 80x80 image, with ``steps`` of
    ``scheduler``."""
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
    from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy

    cfg = DiffusionConfig(
        device=device, noise_scheduler_type=scheduler, num_inference_steps=steps, crop_shape=(76, 76),
        pretrained_backbone_weights=None, use_group_norm=True,
        **({"down_dims": down_dims} if down_dims else {}),
    )  # fmt: skip
    cfg.input_features = {
        schema.STATE: PolicyFeature(type=FeatureType.STATE, shape=(len(schema.STATE_NAMES),)),
        WRIST: PolicyFeature(type=FeatureType.VISUAL, shape=(3, *IMAGE[:2])),
    }
    cfg.output_features = {schema.ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(schema.ACTION_DIM,))}
    policy = DiffusionPolicy(cfg).to(device).eval()
    obs = {
        schema.STATE: torch.randn(1, cfg.n_obs_steps, len(schema.STATE_NAMES), device=device),
        WRIST: torch.rand(1, cfg.n_obs_steps, 3, *IMAGE[:2], device=device),
    }
    batch = {**obs, "observation.images": obs[WRIST][:, :, None]}  # the stacked cameras LeRobot builds
    return lambda: policy.diffusion.generate_actions(batch)


def params(fn: Callable[[], None]) -> int:
    policy = next(c.cell_contents for c in fn.__closure__ if isinstance(c.cell_contents, torch.nn.Module))
    return sum(p.numel() for p in policy.parameters())


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--calls", type=int, default=20, help="timed calls per row (>= 10)")
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--rounds", type=int, default=5, help="the calls are split over this many rounds")
    add_out_argument(parser)
    args = parser.parse_args(argv)
    if args.calls < 10:
        parser.error(f"--calls {args.calls}: at least 10 calls are needed for a p90")

    torch.manual_seed(0)
    rows = {
        "ActionFlow A.1, pose tokens (6 tokens), K=4": actionflow(args.device, 6, 8, None),
        "ActionFlow A.1, wrist camera (`cnn`), 2 tokens + image, K=4": actionflow(args.device, 2, 3, "cnn"),
        "ActionFlow A.1, wrist camera (`resnet18`), 2 tokens + image, K=4": actionflow(
            args.device, 2, 3, "resnet18"
        ),
        "LeRobot Diffusion Policy, state + image, UNet 64-128-256, DDIM 10 steps": diffusion(
            args.device, "DDIM", 10, CPU_UNET
        ),
        "LeRobot Diffusion Policy, state + image, UNet 64-128-256, DDPM 100 steps (its sampler)": diffusion(
            args.device, "DDPM", 100, CPU_UNET
        ),
        "LeRobot Diffusion Policy, state + image, default UNet, DDIM 10 steps": diffusion(
            args.device, "DDIM", 10
        ),
    }
    sync = torch.cuda.synchronize if args.device == "cuda" else (lambda: None)
    times: dict[str, list[float]] = {name: [] for name in rows}
    per_round = -(-args.calls // args.rounds)
    with torch.inference_mode():
        for fn in rows.values():
            for _ in range(args.warmup):
                fn()
        for _ in range(args.rounds):
            for name, fn in rows.items():
                for _ in range(per_round):
                    sync()
                    start = time.perf_counter()
                    fn()
                    sync()
                    times[name].append(1000 * (time.perf_counter() - start))

    device_name = torch.cuda.get_device_name() if args.device == "cuda" else platform.processor() or "CPU"
    first = times[next(iter(rows))]
    base = statistics.median(first)
    lines = [
        f"# Chunk latency of camera policies ({args.device}: {device_name}, torch {torch.__version__}, "
        f"{torch.get_num_threads()} CPU threads)",
        "",
        f"Batch 1, horizon 16, 80x80 RGB image, 2 history steps; median / p90 of {len(first)} "
        f"calls per row after {args.warmup} warm-up calls, rows interleaved over {args.rounds} rounds.",
        "",
        "| policy | parameters | median ms / chunk | p90 ms | vs pose policy |",
        "|---|---|---|---|---|",
    ]
    for name, fn in rows.items():
        median, p90 = statistics.median(times[name]), statistics.quantiles(times[name], n=10)[-1]
        lines.append(f"| {name} | {params(fn):,} | {median:.1f} | {p90:.1f} | {median / base:.1f}x |")
    command = ["python", "-m", "eval.bench.camera_latency", "--device", args.device,
               "--calls", str(args.calls)]  # fmt: skip
    lines += ["", f"Command: `{portable_command(command)}`", "", describe()]
    text = "\n".join(lines)
    print(text)
    write_result(args.out, f"camera_latency_{args.device}.md", text)


if __name__ == "__main__":
    main()
