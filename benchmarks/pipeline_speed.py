"""Speed and memory of odometry methods on the same frames, reported as ratios to a baseline.

Each method runs in its own subprocess so that its peak memory (max RSS) is its own; all of them
read the same frames in the same invocation, and ``--repeat N`` interleaves N rounds of all methods
and reports medians, so machine load affects them alike. Not a test: run

    .venv/bin/python benchmarks/pipeline_speed.py --data-root ../shared/data/kitti-sample --seq 00 \
        --method vcr+kiss-icp --method vcr+icp --baseline kiss-icp --repeat 3 [--frames 0:60] [--stride 1] \
        [--json out.json] [--device auto|cpu|cuda] [--batch-size B] [--network-batch 1 --network-batch 16] \
        [--rss-every 100] [--markdown [--label TEXT] [--no-header]]

A method may carry ``@every-frame`` or ``@on-doubt`` (``vcr+kiss-icp@every-frame``): when its global
registration runs (``--consult``). Without --data-root it generates a 100-frame synthetic sequence.
``--network-batch B`` (repeatable) also times VCR-Net alone: pairs per second of batched inference
(encode both clouds + register) at each batch size, as a ratio to the first. ``--rss-every N``
records resident memory every N frames (``rss_mib_by_frame`` in the JSON).

The per-stage columns come from :mod:`stage_profile` (beside this script): milliseconds per frame in
load, crop, ground removal, sampling, encoder, self-attention, matching (cross-attention and virtual
points), pose head, registration (other methods), polish pre-processing, polish, all of
kiss-icp, and ``other`` (the rest of the wall time: chaining, checks, waiting). Stages that run in
the producer thread overlap the others, so the columns can add up to more than the wall time. Where
the sequence has ground truth, each method's end-point drift and SE(3)-aligned ATE are given beside
its speed (the same in every round: the methods are deterministic). ``--markdown`` prints one markdown
table instead (``--label``: its first column, the data; ``--no-header``: rows only, to append to
another's), as ``benchmarks/frame_time.sh`` does for ``make tables``.
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from doubt_misses import score  # beside this script
from rich.console import Console
from rich.markup import escape
from rich.table import Table
from stage_profile import STAGES, StageProfile  # beside this script


def measure(args: argparse.Namespace) -> dict:
    """Worker: run one method and report its timings and this process's peak memory."""
    from vcr_odom.data import open_sequence
    from vcr_odom.data.selection import select_frames
    from vcr_odom.odometry import build_odometry, parse_method_spec, run_odometry

    sequence = open_sequence(args.seq, data_root=args.data_root)
    indices = select_frames(len(sequence), args.frames, args.stride)
    spec, _, consult = args.worker.partition("@")
    options: dict = {"consult": consult} if consult else {}
    if parse_method_spec(spec)[0] == "vcr":
        options |= {"weights": args.weights, "device": args.device, "batch_size": args.batch_size}
        options |= {"num_points": args.vcr_points}
    method = build_odometry(spec, **options)
    profile = StageProfile()
    rss: list[tuple[int, float]] = []

    done = 0

    def sample_rss(index: int, *_: object) -> None:
        nonlocal done
        if done % args.rss_every == 0:
            rss.append((index, _current_rss_mib()))
        done += 1

    with profile.patched():
        run = run_odometry(sequence, method, indices, on_frame=sample_rss if args.rss_every else None)
    truth = sequence.gt_poses
    stages = {stage: profile.seconds.get(stage, 0.0) for stage in STAGES}
    stages["other"] = max(run.wall_seconds - sum(stages.values()), 0.0)
    return {
        "method": args.worker,
        "frames": len(run.frame_indices),
        "wall_seconds": run.wall_seconds,
        "frames_per_second": run.frames_per_second,
        "stage_seconds": {name: seconds for name, seconds in stages.items() if seconds > 0},
        "loop_seconds": run.stage_seconds,
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "rss_mib_by_frame": rss,
        **score(run.poses, None if truth is None else truth[run.frame_indices]),
    }


def _current_rss_mib() -> float:
    """Resident memory now (Linux /proc), for the memory-over-frames check."""
    with open("/proc/self/statm") as statm:
        pages = int(statm.read().split()[1])
    return pages * resource.getpagesize() / 2**20


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
    if args.vcr_points:
        command += ["--vcr-points", str(args.vcr_points)]
    command += ["--device", args.device]
    if args.batch_size is not None:
        command += ["--batch-size", str(args.batch_size)]
    if args.rss_every:
        command += ["--rss-every", str(args.rss_every)]
    completed = subprocess.run(command, capture_output=True, text=True, check=False)
    if completed.returncode != 0:
        raise SystemExit(f"{method} failed:\n{completed.stderr[-2000:]}")
    return json.loads(completed.stdout.strip().splitlines()[-1])


def median_of(runs: list[dict]) -> dict:
    """One method's rounds as one row: median fps, wall and stage times; the largest peak memory."""
    median = statistics.median
    row = dict(runs[len(runs) // 2])
    row["rounds"] = len(runs)
    row["frames_per_second"] = median(r["frames_per_second"] for r in runs)
    row["wall_seconds"] = median(r["wall_seconds"] for r in runs)
    stages = {stage for r in runs for stage in r["stage_seconds"]}
    row["stage_seconds"] = {s: median(r["stage_seconds"].get(s, 0.0) for r in runs) for s in stages}
    row["peak_rss_mib"] = max(r["peak_rss_mib"] for r in runs)
    row["fps_rounds"] = [r["frames_per_second"] for r in runs]
    return row


def report(results: list[dict], baseline: str) -> Table:
    base = next(r for r in results if r["method"] == baseline)
    present = {stage for r in results for stage in r["stage_seconds"]}
    stages = [stage for stage in (*STAGES, "other") if stage in present]
    rounds = base.get("rounds", 1)
    title = f"{base['frames']} frames; ratios against {baseline} in the same run"
    table = Table(title=title + (f" (medians of {rounds} interleaved rounds)" if rounds > 1 else ""))
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


MARKDOWN_STAGES = {
    "sampling": "sampling",
    "ground removal": "ground",
    "encoder": "encoder",
    "self-attention": "attention",
    "matching": "matching",
    "pose head": "head",
    "registration": "registration",
    "polish prepare": "polish prepare",
    "polish": "polish",
    "kiss-icp": "kiss-icp",
    "load": "load",
}
"""The stages the markdown table names, in its words (crop and ``other`` are left out: small, or the
rest of the wall time)."""


def markdown(results: list[dict], baseline: str, label: str, header: bool = True) -> str:
    """One markdown row per method: speed against ``baseline``, accuracy, where a frame's time goes."""
    base = next(r for r in results if r["method"] == baseline)
    lines = []
    if header:
        lines += [
            f"| data | method | frames/s | against {baseline} | end-point % | ATE m (SE3) | "
            "where a frame's time goes [ms] |",
            "|---|---|---|---|---|---|---|",
        ]
    for r in results:
        spent = [
            f"{name} {1000.0 * r['stage_seconds'][stage] / r['frames']:.1f}"
            for stage, name in MARKDOWN_STAGES.items()
            if r["stage_seconds"].get(stage, 0.0) * 1000.0 / r["frames"] >= 0.05
        ]
        accuracy = [
            f"{r['end_point_pct']:.2f}" if "end_point_pct" in r else "-",
            f"{r['ate_m']:.3f}" if "ate_m" in r else "-",
        ]
        lines.append(
            f"| {label} | `{r['method']}` | {r['frames_per_second']:.1f} | "
            f"{r['frames_per_second'] / base['frames_per_second']:.2f}x | {' | '.join(accuracy)} | "
            f"{', '.join(spent)} |"
        )
    return "\n".join(lines)


def network_throughput(args: argparse.Namespace, data_root: Path) -> list[dict]:
    """Pairs per second of VCR-Net alone (both encodings + registration) at each ``--network-batch``."""
    import time

    import numpy as np
    import torch

    from vcr_odom.data import open_sequence
    from vcr_odom.data.selection import select_frames
    from vcr_odom.registration.vcr import VcrRegistrar

    registrar = VcrRegistrar(args.weights, args.device, num_points=args.vcr_points)
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
    parser.add_argument(
        "--method",
        action="append",
        default=[],
        help="method to time (repeat); SPEC@every-frame or @on-doubt sets --consult",
    )
    parser.add_argument("--baseline", default="kiss-icp")
    parser.add_argument("--frames", default=None)
    parser.add_argument("--stride", type=int, default=1)
    parser.add_argument("--weights", type=Path, help="VCR-Net weights for --method vcr")
    parser.add_argument("--vcr-points", type=int, help="points VCR-Net is fed (default: the weights' own)")
    parser.add_argument(
        "--device", default="auto", choices=["auto", "cpu", "cuda"], help="where VCR-Net runs"
    )
    parser.add_argument("--batch-size", type=int, help="VCR pairs per network call (default: 16 CUDA, 1 CPU)")
    parser.add_argument("--network-batch", type=int, action="append", default=[], help="time VCR-Net alone")
    parser.add_argument("--json", type=Path, help="also write the raw figures here")
    parser.add_argument(
        "--repeat", type=int, default=1, help="rounds over all methods, interleaved; the table shows medians"
    )
    parser.add_argument("--rss-every", type=int, default=0, help="sample resident memory every N frames")
    parser.add_argument("--markdown", action="store_true", help="print one markdown table instead")
    parser.add_argument("--label", default="", help="the markdown table's first column (the data)")
    parser.add_argument("--no-header", action="store_true", help="markdown rows only")
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
        rounds = [[run_worker(method, args, data_root) for method in methods] for _ in range(args.repeat)]
        results = [median_of([r[i] for r in rounds]) for i in range(len(methods))]
        network = network_throughput(args, data_root) if args.network_batch else []
    if args.markdown:
        print(markdown(results, args.baseline, args.label, header=not args.no_header))
    else:
        Console(width=200).print(report(results, args.baseline))
    console = Console(width=200)
    if network:
        console.print(network_report(network))
    if args.json:
        args.json.write_text(json.dumps({"odometry": results, "network": network}, indent=2) + "\n")


if __name__ == "__main__":
    main()
