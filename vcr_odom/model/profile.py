"""Size and cost of a VCR-Net configuration: parameters, FLOPs per pair, measured pairs per second.

FLOPs come from ``torch.utils.flop_counter.FlopCounterMode`` on one batch-1 forward (matmuls, linear
layers and scaled dot-product attention, counted as 2 per multiply-add); elementwise work, top-k, gathers
and the 3x3 SVD are not counted. Run ``python -m vcr_odom.model.profile`` for both presets and the
shipped weights.
"""

from __future__ import annotations

import statistics
import time
from typing import Any

import torch
from torch import nn
from torch.utils.flop_counter import FlopCounterMode, register_flop_formula, sdpa_flop_count

from vcr_odom.model.config import PRESETS, VcrConfig
from vcr_odom.model.network import VCRNet

_CPU_ATTENTION = getattr(torch.ops.aten, "_scaled_dot_product_flash_attention_for_cpu", None)
if _CPU_ATTENTION is not None:
    # torch's counter knows the CUDA attention kernels but not the CPU one that
    # scaled_dot_product_attention dispatches to here, so without this the attention's N² products
    # would be missing from the count; the formula is torch's own for the other kernels.
    try:

        @register_flop_formula(_CPU_ATTENTION)
        def _cpu_attention_flops(query_shape, key_shape, value_shape, *args, out_shape=None, **kwargs) -> int:  # type: ignore[no-untyped-def]
            return sdpa_flop_count(query_shape, key_shape, value_shape)

    except RuntimeError:  # a later torch that registers it itself
        pass


def parameter_count(model: nn.Module) -> dict[str, int]:
    """Trainable and total parameters, and the trainable count of each top-level sub-module."""
    counts = {
        "total": sum(p.numel() for p in model.parameters()),
        "trainable": sum(p.numel() for p in model.parameters() if p.requires_grad),
    }
    for name, child in model.named_children():
        counts[name] = sum(p.numel() for p in child.parameters() if p.requires_grad)
    return counts


def _random_pair(config: VcrConfig, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    source = torch.randn(1, config.num_points, 3, generator=generator) * 15.0
    return source, source + 0.5


def flops_per_pair(config: VcrConfig) -> int:
    """Counted FLOPs of one forward pass (both clouds encoded) at batch 1 and N = num_points."""
    model = VCRNet(config).eval()
    source, target = _random_pair(config)
    counter = FlopCounterMode(display=False)
    with torch.no_grad(), counter:
        model(source, target)
    return int(counter.get_total_flops())


def pairs_per_second(config: VcrConfig, threads: int = 2, repeats: int = 20, warmup: int = 3) -> float:
    """Measured batch-1 inference throughput on the CPU with ``threads`` torch threads.

    One over the median time of ``repeats`` forward passes (the median resists other processes'
    bursts on a shared machine).
    """
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        model = VCRNet(config).eval()
        source, target = _random_pair(config)
        with torch.inference_mode():
            for _ in range(warmup):
                model(source, target)
            times = []
            for _ in range(repeats):
                start = time.perf_counter()
                model(source, target)
                times.append(time.perf_counter() - start)
    finally:
        torch.set_num_threads(previous)
    return 1.0 / statistics.median(times)


def describe(config: VcrConfig | str, measure_speed: bool = False) -> dict[str, Any]:
    """Config, parameter counts and FLOPs/pair (and measured CPU pairs/s on request) as one dict."""
    if isinstance(config, str):
        config = VcrConfig.preset(config)
    info: dict[str, Any] = {
        "config": config.to_dict(),
        "parameters": parameter_count(VCRNet(config)),
        "flops_per_pair": flops_per_pair(config),
        "key_points": config.key_points(config.num_points),
    }
    if measure_speed:
        info["cpu_pairs_per_second_2_threads"] = pairs_per_second(config)
    return info


def main() -> None:
    """Both presets, then the shipped file's configuration: it runs with more points than its preset
    (the point count is an inference setting, ``weights/MODEL_CARD.md``), which is what it costs."""
    from vcr_odom.model.weights import default_weights_path, read_weights

    configs: list[tuple[str, VcrConfig | str]] = [(name, name) for name in PRESETS]
    shipped = default_weights_path("default", must_exist=False)
    if shipped.is_file():
        configs.append(("shipped", read_weights(shipped)[1]))
    for name, config in configs:
        info = describe(config, measure_speed=True)
        params = info["parameters"]["trainable"]
        print(
            f"{name:8s} N={info['config']['num_points']:5d} params={params:,} "
            f"GFLOPs/pair={info['flops_per_pair'] / 1e9:.3f} "
            f"CPU(2 threads) pairs/s={info['cpu_pairs_per_second_2_threads']:.1f}"
        )


if __name__ == "__main__":
    main()
