"""Latency of one ActionFlow action chunk (H = 16) at K = 1, 2, 4, 10 Euler steps, batch 1.

    python -m eval.bench.latency [--device cpu|cuda] [--calls 100] [--architecture ipa] [--out eval/results]

Default model, 2 history steps x 6 tokens. Prints a table (median / p90 ms over `--calls` timed calls after
warm-up) and the parameter count, and writes it to ``<out>/latency_<device>.md`` (default out:
``outputs/bench``; the committed tables are in eval/results/).
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import torch

from eval.bench.output import add_out_argument, write_result
from eval.provenance import describe, portable_command
from lerobot_actionflow import ActionFlowConfig, ActionFlowPolicy, schema
from lerobot_actionflow.core import geometry as g

N_TOKENS, N_FEATURES = 6, 8


def build(device: str, architecture: str, k: int) -> ActionFlowPolicy:
    cfg = ActionFlowConfig(device=device, architecture=architecture, num_inference_steps=k)
    shapes = schema.token_shapes(N_TOKENS, N_FEATURES)
    cfg.input_features, cfg.output_features = schema.policy_features(shapes)
    return ActionFlowPolicy(cfg).to(device).eval()


def observation(device: str) -> dict[str, torch.Tensor]:
    rot = g.random_rotation((1, 2, N_TOKENS))
    poses = g.rt_to_pose9(rot, torch.randn(1, 2, N_TOKENS, 3) * 0.2)
    return {
        schema.TOKEN_POSES: poses.to(device),
        schema.TOKEN_FEATURES: torch.randn(1, 2, N_TOKENS, N_FEATURES, device=device),
    }


def time_chunk(policy: ActionFlowPolicy, obs: dict, calls: int, warmup: int) -> list[float]:
    sync = torch.cuda.synchronize if obs[schema.TOKEN_POSES].is_cuda else (lambda: None)
    times = []
    with torch.inference_mode():
        for i in range(warmup + calls):
            sync()
            start = time.perf_counter()
            policy.predict_action_chunk(obs)
            sync()
            if i >= warmup:
                times.append((time.perf_counter() - start) * 1000)
    return times


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--architecture", default="ipa", choices=["ipa", "multi_token", "single_token"])
    parser.add_argument("--calls", type=int, default=100, help="timed calls per K (>= 50)")
    parser.add_argument("--warmup", type=int, default=20)
    add_out_argument(parser)
    args = parser.parse_args(argv)

    torch.manual_seed(0)
    device_name = (
        torch.cuda.get_device_name() if args.device == "cuda" else f"{platform.processor() or 'CPU'}"
    )
    obs = observation(args.device)
    lines = [
        f"# ActionFlow chunk latency ({args.device}: {device_name}, torch {torch.__version__}, "
        f"{torch.get_num_threads()} CPU threads)",
        "",
        f"Default `{args.architecture}` model, batch 1, 2 history steps x {N_TOKENS} tokens, horizon 16; "
        f"median / p90 of {args.calls} calls after {args.warmup} warm-up calls.",
        "",
        "| K (Euler steps) | median ms / chunk | p90 ms | chunks / s |",
        "|---|---|---|---|",
    ]
    params = None
    for k in (1, 2, 4, 10):
        policy = build(args.device, args.architecture, k)
        params = sum(p.numel() for p in policy.parameters())
        times = time_chunk(policy, obs, args.calls, args.warmup)
        median, p90 = statistics.median(times), statistics.quantiles(times, n=10)[-1]
        lines.append(f"| {k} | {median:.2f} | {p90:.2f} | {1000 / median:.0f} |")
    command = ["python", "-m", "eval.bench.latency", "--device", args.device, "--architecture",
               args.architecture, "--calls", str(args.calls)]  # fmt: skip
    lines += ["", f"Parameters: {params:,}", "", f"Command: `{portable_command(command)}`", "", describe()]
    text = "\n".join(lines)
    print(text)
    suffix = "" if args.architecture == "ipa" else f"_{args.architecture}"
    write_result(args.out, f"latency_{args.device}{suffix}.md", text)


if __name__ == "__main__":
    main()
