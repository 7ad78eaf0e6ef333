"""What the kiss-icp polish's convergence criterion buys and costs: accuracy and CPU per frame.

Not a test. Runs the default method (VCR-Net + kiss-icp polish) and kiss-icp itself with each
registration convergence criterion (kiss-icp's own default is 1e-4; the polish uses
``POLISH_CONVERGENCE``) on a KITTI-layout sequence at each stride and, with ``--synthetic-frames N``,
on synthetic drives that nothing was tuned or trained on (seeds 71-74, one per sensor model):

    .venv/bin/python benchmarks/polish_convergence.py --data-root ../shared/data/kitti-sample --seq 00 \\
        --stride 1 --stride 5 --stride 10 [--criterion 1e-4 --criterion 1e-3] [--synthetic-frames 200]

prints one markdown table: end-point drift, per-pair RMSE and process CPU milliseconds per frame
(both cores count, so CPU time, not wall time, is what the criterion changes) for each method,
criterion and stride.
"""

from __future__ import annotations

import time
import warnings
from pathlib import Path
from typing import Any

from sequence_args import sequence_parser

HELD_OUT_DRIVES = (
    ("hdl64", 71, "suburban"),
    ("hdl32", 72, "avenue"),
    ("vlp16", 73, "oldtown"),
    ("os128", 74, "highway"),
)
"""(sensor, seed, scene) of the synthetic drives: seeds no cache or tuning run used."""


def _method(name: str, criterion: float, weights: Path | None, device: str) -> Any:
    from vcr_odom.odometry import build_odometry
    from vcr_odom.registration.kiss import kiss_config

    if name == "kiss-icp":
        return build_odometry("kiss-icp", convergence_criterion=criterion)
    polish = {"config": kiss_config(convergence_criterion=criterion)}
    return build_odometry("vcr+kiss-icp", weights=weights, device=device, polish_options=polish)


def _rows(label: str, sequence: Any, indices: list[int], gt: Any, args: Any) -> list[list[str]]:
    from vcr_odom.metrics import evaluate
    from vcr_odom.odometry import run_odometry

    rows = []
    for criterion in args.criterion:
        for name in ("vcr+kiss-icp", "kiss-icp"):
            method = _method(name, criterion, args.weights, args.device)
            started = time.process_time()
            run = run_odometry(sequence, method, indices)
            cpu_ms = 1000 * (time.process_time() - started) / len(indices)
            report = evaluate(run.poses, gt)
            rows.append(
                [
                    label,
                    name,
                    f"{criterion:g}",
                    f"{report.endpoint.trans_error_percent:.2f}",
                    f"{report.pairs.rot_rmse_deg:.4f}",
                    f"{report.pairs.trans_rmse_m:.4f}",
                    f"{cpu_ms:.1f}",
                ]
            )
    return rows


def main() -> None:
    parser = sequence_parser(__doc__)
    parser.add_argument("--stride", type=int, action="append", help="repeatable; default 1")
    parser.add_argument("--criterion", type=float, action="append", help="repeatable; default 1e-4 and 1e-3")
    parser.add_argument("--synthetic-frames", type=int, default=0, help="frames per held-out synthetic drive")
    parser.add_argument("--weights", type=Path, default=None)
    parser.add_argument("--device", default="cpu")
    args = parser.parse_args()
    args.criterion = args.criterion or [1e-4, 1e-3]
    warnings.simplefilter("ignore")

    from vcr_odom.data import open_sequence
    from vcr_odom.data.selection import select_frames
    from vcr_odom.geometry import normalise_to_first
    from vcr_odom.odometry.outputs import ground_truth_for
    from vcr_odom.synth import SynthSequence

    rows: list[list[str]] = []
    sequence = open_sequence(args.seq, data_root=args.data_root)
    for stride in args.stride or [1]:
        indices = select_frames(len(sequence), args.frames, stride)
        for row in _rows(
            f"{sequence.name} s{stride}", sequence, indices, ground_truth_for(sequence, indices), args
        ):
            rows.append(row)
    if args.synthetic_frames:
        for sensor, seed, scene in HELD_OUT_DRIVES:
            drive = SynthSequence(
                frames=args.synthetic_frames, seed=seed, sensor=sensor, scene=scene, speed=12.0
            )
            for stride in args.stride or [1]:
                indices = list(range(0, len(drive), stride))
                gt = normalise_to_first(drive.gt_poses[indices])
                for row in _rows(f"{sensor} seed {seed} s{stride}", drive, indices, gt, args):
                    rows.append(row)
    print(markdown_table(rows))


COLUMNS = (
    "data, stride",
    "method",
    "criterion",
    "end-point [%]",
    "rot RMSE [°]",
    "trans RMSE [m]",
    "CPU [ms/frame]",
)


def markdown_table(rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(COLUMNS) + " |", "|---|---|" + "---:|" * (len(COLUMNS) - 2)]
    return "\n".join(lines + ["| " + " | ".join(row) + " |" for row in rows])


if __name__ == "__main__":
    main()
