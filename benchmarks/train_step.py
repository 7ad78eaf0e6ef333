"""Cost of one VCR-Net training step on this machine: seconds per 1,000 pairs, by objective and point
count, and the encoder's neighbour max against ``amax`` (the baseline, in the same run). Not a test.

Random street-like clouds (the cost does not depend on the data), batch 8, Adam, the shipped
configuration at an 80 m crop; the median of --repeat timed steps after one warm-up step.

    .venv/bin/python benchmarks/train_step.py --threads 2 --repeat 5
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import torch

import vcr_odom.model.encoder as encoder_module
import vcr_odom.model.invariant_encoder as invariant_module
from vcr_odom.model.config import VcrConfig
from vcr_odom.model.network import VCRNet
from vcr_odom.training.config import TrainConfig
from vcr_odom.training.tasks import Registration


def step_seconds(points: int, objective: str, batch: int, repeat: int) -> float:
    torch.manual_seed(0)
    net = VCRNet(VcrConfig.preset("default").with_changes(input_max_range=80.0)).train()
    optimiser = torch.optim.Adam(net.parameters(), 1e-4)
    source = torch.randn(batch, points, 3) * torch.tensor([20.0, 20.0, 2.0])
    transform = torch.eye(4).repeat(batch, 1, 1)
    transform[:, 0, 3] = 1.0
    pair = {"source": source, "target": source + transform[:, :3, 3].unsqueeze(1), "transform": transform}
    config, task = TrainConfig(objective=objective), Registration()
    times = []
    for index in range(repeat + 1):
        started = time.perf_counter()
        loss, _ = task.loss(net, pair, config)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        if index:
            times.append(time.perf_counter() - started)
    return statistics.median(times)


def with_neighbour_max(function: Callable[[torch.Tensor], torch.Tensor]) -> None:
    encoder_module.neighbour_max = function
    invariant_module.neighbour_max = function


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--batch", type=int, default=8)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    chosen = encoder_module.neighbour_max
    print("| points | objective | s / 1,000 pairs | with amax (baseline) | ratio |")
    print("|---|---|---|---|---|")
    for points in (512, 1024):
        for objective in ("correspondence", "matching"):
            with_neighbour_max(lambda edges: edges.amax(dim=2))
            baseline = step_seconds(points, objective, args.batch, args.repeat)
            with_neighbour_max(chosen)
            seconds = step_seconds(points, objective, args.batch, args.repeat)
            per_thousand = 1000.0 / args.batch
            print(
                f"| {points} | {objective} | {seconds * per_thousand:.0f} | {baseline * per_thousand:.0f} | "
                f"{baseline / seconds:.2f}x |"
            )


if __name__ == "__main__":
    main()
