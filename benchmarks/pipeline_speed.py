"""Speed and memory of odometry methods on the same frames, reported as ratios to a baseline.

Each method runs in its own subprocess so that its peak memory (max RSS) is its own; all of them
read the same frames in the same invocation, so machine load affects them alike. Not a test: run

    .venv/bin/python benchmarks/pipeline_speed.py --data-root ../shared/data/kitti-sample --seq 00 \
        --method vcr+icp --method icp --baseline kiss-icp [--frames 0:60] [--stride 1] [--json out.json] \
        [--device auto|cpu|cuda] [--batch-size B] [--network-batch 1 --network-batch 16]

Without --data-root it generates a 100-frame synthetic sequence in a temporary folder.
``--network-batch B`` (repeatable) also times VCR-Net alone on the benchmark's frames: pairs per second
of batched inference (encode both clouds + register) at each batch size, as a ratio to the first.
Per-stage seconds, timed by the frame loop (``vcr_odom.odometry.loop``): load (reading frames), prepare
(per-frame work: crop, ground removal, down-sampling, the encoder, the polish's cloud), register
(pairwise estimates), advance (plausibility check, polish, chaining), step (a method with its own
state, kiss-icp), bookkeeping (the rest: callbacks, I/O).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

from rich.console import Console
from rich.markup import escape
from rich.table import Table


def measure(args: argparse.Namespace) -> dict:
    """Worker: run one method and report its timings and this process's peak memory."""
    from vcr_odom.data import open_sequence
    from vcr_odom.data.selection import select_frames
    from vcr_odom.odometry import build_odometry, parse_method_spec, run_odometry

    sequence = open_sequence(args.seq, data_root=args.data_root)
    indices = select_frames(len(sequence), args.frames, args.stride)
    options: dict = {}
    if parse_method_spec(args.worker)[0] == "vcr":
        options = {"weights": args.weights, "device": args.device, "batch_size": args.batch_size}
    method = build_odometry(args.worker, **options)
    run = run_odometry(sequence, method, indices)
    return {
        "method": args.worker,
        "frames": len(run.frame_indices),
        "wall_seconds": run.wall_seconds,
        "frames_per_second": run.frames_per_second,
        "stage_seconds": run.stage_seconds,
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }


def run_worker(method: str, args: argparse.Namespace, data_root: Path) -> dict:
    command = [
        sys.executable,
        __file__,
        "--worker",
        method,
        "--data-root",
        str(data_root),
        "--seq",
        args.seq,
        "--stride",
        str(args.stride),
    ]
    if args.frames:
        command += ["--frames", args.frames]
    if args.weights:
        command += ["--weights", str(args.weights)]
    command += ["--device", args.device]
    if args.batch_size is not None:
        command += ["--batch-size", str(args.batch_size)]
    completed = subprocess.run(command, capture_output=True, text=True, check=False)
    if completed.returncode != 0:
        raise SystemExit(f"{method} failed:\n{completed.stderr[-2000:]}")
    return json.loads(completed.stdout.strip().splitlines()[-1])


def report(results: list[dict], baseline: str) -> Table:
    base = next(r for r in results if r["method"] == baseline)
    stages = sorted({stage for r in results for stage in r["stage_seconds"]})
    table = Table(title=f"{base['frames']} frames; ratios against {baseline} in the same run")
    for header in (
        "method",
        "fps",
        f"fps / {baseline}",
        "ms/frame",
        *[f"{s} [ms/frame]" for s in stages],
        "peak RSS [MiB]",
    ):
        table.add_column(escape(header), justify="left" if header == "method" else "right")
    for r in results:
        per_frame = {
            s: f"{1000.0 * r['stage_seconds'][s] / r['frames']:.1f}" if s in r["stage_seconds"] else "–"
            for s in stages
        }
        table.add_row(
            r["method"],
            f"{r['frames_per_second']:.1f}",
            f"{r['frames_per_second'] / base['frames_per_second']:.2f}",
            f"{1000.0 * r['wall_seconds'] / r['frames']:.1f}",
            *[per_frame[s] for s in stages],
            f"{r['peak_rss_mib']:.0f}",
        )
    return table


def network_throughput(args: argparse.Namespace, data_root: Path) -> list[dict]:
    """Pairs per second of VCR-Net alone (both encodings + registration) at each ``--network-batch``."""
    import time

    import numpy as np
    import torch

    from vcr_odom.data import open_sequence
    from vcr_odom.data.selection import select_frames
    from vcr_odom.registration.vcr import VcrRegistrar

    registrar = VcrRegistrar(args.weights, args.device)
    sequence = open_sequence(args.seq, data_root=data_root)
    indices = select_frames(len(sequence), args.frames, args.stride)
    largest = max(args.network_batch)
    clouds = [registrar.network_input(sequence.frame(i)) for i in indices[: largest + 1]]
    while len(clouds) < largest + 1:
        clouds += clouds[: largest + 1 - len(clouds)]
    points = torch.as_tensor(np.stack(clouds), device=registrar.device)
    rows = []
    for batch in args.network_batch:
        source, target = points[1 : batch + 1], points[:batch]
        with torch.inference_mode():
            registrar.model(source, target)  # warm-up (allocations, kernel selection)
            if registrar.device.type == "cuda":
                torch.cuda.synchronize()
            repeats, started = 0, time.perf_counter()
            while repeats < 3 or time.perf_counter() - started < 2.0:
                registrar.model(source, target)
                repeats += 1
            if registrar.device.type == "cuda":
                torch.cuda.synchronize()
        seconds = time.perf_counter() - started
        rows.append(
            {"batch": batch, "pairs_per_second": batch * repeats / seconds, "device": str(registrar.device)}
        )
    return rows


def network_report(rows: list[dict]) -> Table:
    base = rows[0]["pairs_per_second"]
    table = Table(title=f"VCR-Net alone on {rows[0]['device']}: batched inference")
    for header in ("batch", "pairs / s", f"ratio to batch {rows[0]['batch']}"):
        table.add_column(header, justify="right")
    for row in rows:
        table.add_row(
            str(row["batch"]), f"{row['pairs_per_second']:.1f}", f"{row['pairs_per_second'] / base:.2f}"
        )
    return table


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data-root", type=Path)
    parser.add_argument("--seq", default="00")
    parser.add_argument("--method", action="append", default=[], help="method to time (repeat)")
    parser.add_argument("--baseline", default="kiss-icp")
    parser.add_argument("--frames", default=None)
    parser.add_argument("--stride", type=int, default=1)
    parser.add_argument("--weights", type=Path, help="VCR-Net weights for --method vcr")
    parser.add_argument(
        "--device", default="auto", choices=["auto", "cpu", "cuda"], help="where VCR-Net runs"
    )
    parser.add_argument("--batch-size", type=int, help="VCR pairs per network call (default: 16 CUDA, 1 CPU)")
    parser.add_argument("--network-batch", type=int, action="append", default=[], help="time VCR-Net alone")
    parser.add_argument("--json", type=Path, help="also write the raw figures here")
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(measure(args)))
        return
    methods = list(dict.fromkeys([*(args.method or ["icp"]), args.baseline]))
    with tempfile.TemporaryDirectory() as scratch:
        data_root = args.data_root
        if data_root is None:
            from vcr_odom.synth import generate_sequence

            data_root = Path(scratch)
            generate_sequence(data_root, seq=args.seq, frames=100, seed=0)
        results = [run_worker(method, args, data_root) for method in methods]
        network = network_throughput(args, data_root) if args.network_batch else []
    console = Console(width=200)
    console.print(report(results, args.baseline))
    if network:
        console.print(network_report(network))
    if args.json:
        args.json.write_text(json.dumps({"odometry": results, "network": network}, indent=2) + "\n")


if __name__ == "__main__":
    main()
