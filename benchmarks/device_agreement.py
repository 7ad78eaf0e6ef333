"""VCR-Net on several devices and batch sizes, the same pairs: do they give the same poses, and how fast.

The odometry batches 16 pairs per network call on CUDA and one on a CPU (vcr_odom/registration/vcr.py
``GPU_BATCH_SIZE``); this checks that the batched CUDA path measures what the CPU does, pair by pair,
and reports pairs per second as a ratio to the first row. Two steps, because a GPU image may hold torch
but not open3d, which the pre-processing needs:

    # here: ground removal and sampling once, into the network's inputs and the true motions
    .venv/bin/python benchmarks/device_agreement.py prepare --data-root WORK/sequences/.. --seq 990 \
        --frames 0:200 --gap 1 --gap 5 --out pairs.npz
    # where CUDA is (torch, numpy, pydantic, safetensors, rich):
    python benchmarks/device_agreement.py measure --pairs pairs.npz --run cpu:1 --run cuda:1 --run cuda:16 \
        [--json out.json]

Every row registers every pair (encoding each frame once, as the odometry does) after one warm-up
batch; its ``largest difference`` columns are against the first row, pair by pair.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from vcr_odom.geometry import invert, motion_difference
from vcr_odom.io import replacing


def prepare(args: argparse.Namespace) -> None:
    """Write the network's input for every frame in ``--frames`` and each ``--gap`` pair's true motion."""
    from vcr_odom.data import open_sequence
    from vcr_odom.data.selection import select_frames
    from vcr_odom.registration.vcr import VcrRegistrar

    registrar = VcrRegistrar(args.weights, "cpu")
    sequence = open_sequence(args.seq, data_root=args.data_root)
    if sequence.gt_poses is None:
        sys.exit(
            f"{args.data_root}/{args.seq}: no ground-truth poses; the pairs' true motions come from them"
        )
    indices = select_frames(len(sequence), args.frames, 1)
    inputs = np.stack([registrar.network_input(sequence.frame(i)) for i in indices])
    pairs, motions = [], []
    for gap in args.gap:
        for k in range(len(indices) - gap):
            source, target = indices[k + gap], indices[k]
            pairs.append((k + gap, k))
            motions.append(invert(sequence.gt_poses[target]) @ sequence.gt_poses[source])  # T_target_source
    if not pairs:
        sys.exit(f"--frames {args.frames} holds no pair {args.gap} frames apart")
    with replacing(args.out, suffix=".npz") as temporary:
        np.savez_compressed(temporary, inputs=inputs, pairs=np.array(pairs), motions=np.array(motions))
    print(f"{len(indices)} frames, {len(pairs)} pairs -> {args.out}")


def measure_run(weights: Path | None, device: str, batch: int, data: dict) -> dict:
    """Every pair's estimate on ``device`` at ``batch`` pairs per call, and the wall time of it all."""
    import torch

    from vcr_odom.registration.vcr import VcrRegistrar

    registrar = VcrRegistrar(weights, device, batch_size=batch)
    inputs, pairs = list(data["inputs"]), data["pairs"]

    def synchronise() -> None:
        if registrar.device.type == "cuda":
            torch.cuda.synchronize()

    def all_pairs(count: int) -> list[np.ndarray]:
        frames = []
        for start in range(0, len(inputs), batch):
            frames += registrar.encode_inputs(inputs[start : start + batch])
        estimates = []
        for start in range(0, count, batch):
            chunk = [(frames[s], frames[t]) for s, t in pairs[start : min(start + batch, count)]]
            estimates += [result.transform for result in registrar.register_batch(chunk)]
        return estimates

    all_pairs(min(batch, len(pairs)))  # warm-up: allocations, kernel choice
    synchronise()
    started = time.perf_counter()
    estimates = all_pairs(len(pairs))
    synchronise()
    seconds = time.perf_counter() - started
    name = torch.cuda.get_device_name(registrar.device) if registrar.device.type == "cuda" else "cpu"
    return {
        "device": device,
        "device_name": name,
        "batch": batch,
        "threads": torch.get_num_threads(),
        "seconds": seconds,
        "pairs_per_second": len(pairs) / seconds,
        "estimates": estimates,
    }


def measure(args: argparse.Namespace) -> None:
    with np.load(args.pairs) as archive:
        data = {key: archive[key] for key in archive.files}
    rows = []
    for spec in args.run:
        device, _, batch = spec.partition(":")
        rows.append(measure_run(args.weights, device, int(batch or 1), data))
    reference = rows[0]["estimates"]
    for row in rows:
        truth = [motion_difference(m, e) for m, e in zip(data["motions"], row["estimates"], strict=True)]
        agreement = [motion_difference(r, e) for r, e in zip(reference, row["estimates"], strict=True)]
        row |= {
            "median_error_m": float(np.median([t for t, _ in truth])),
            "median_error_deg": float(np.median([r for _, r in truth])),
            "largest_difference_m": max(t for t, _ in agreement),
            "largest_difference_deg": max(r for _, r in agreement),
        }
    table = Table(title=f"VCR-Net on {len(data['pairs'])} pairs ({len(data['inputs'])} frames)")
    headers = ("device", "batch", "pairs / s", "ratio", "median error m / deg", "largest difference m / deg")
    for header in headers:
        table.add_column(header, justify="right")
    for row in rows:
        table.add_row(
            f"{row['device']} ({row['device_name']}, {row['threads']} threads)",
            str(row["batch"]),
            f"{row['pairs_per_second']:.1f}",
            f"{row['pairs_per_second'] / rows[0]['pairs_per_second']:.2f}",
            f"{row['median_error_m']:.4f} / {row['median_error_deg']:.3f}",
            f"{row['largest_difference_m']:.2e} / {row['largest_difference_deg']:.2e}",
        )
    Console().print(table)
    if args.json:
        for row in rows:
            row["estimates"] = np.asarray(row["estimates"]).tolist()
        args.json.write_text(json.dumps(rows, indent=1))


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--weights", type=Path, help="VCR-Net weights (default: the shipped file)")
    commands = parser.add_subparsers(dest="command", required=True)
    made = commands.add_parser("prepare", help="pre-process frames into the network's inputs (needs open3d)")
    made.add_argument("--data-root", type=Path, required=True)
    made.add_argument("--seq", required=True)
    made.add_argument("--frames", default=None, help="A:B")
    made.add_argument("--gap", type=int, action="append", help="pairs this many frames apart (repeat)")
    made.add_argument("--out", type=Path, required=True)
    timed = commands.add_parser("measure", help="register every pair per --run and compare")
    timed.add_argument("--pairs", type=Path, required=True)
    timed.add_argument("--run", action="append", required=True, help="DEVICE:BATCH, e.g. cuda:16 (repeat)")
    timed.add_argument("--json", type=Path)
    args = parser.parse_args()
    if args.command == "prepare":
        args.gap = args.gap or [1]
        prepare(args)
    else:
        measure(args)


if __name__ == "__main__":
    main()
