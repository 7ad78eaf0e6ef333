"""Why each polish also starts from the motion prior: VCR + polish with and without that second start.

Not a test. For each stride, runs `vcr+icp` and `vcr+kiss-icp` twice on the same frames: with both
starts (the default: the global estimate and the constant-velocity prior, the better fit wins) and
with the global estimate alone (for kiss-icp: the estimate *in place of* its prediction):

    .venv/bin/python benchmarks/polish_starts.py --data-root ../shared/data/kitti-sample --seq 00 \\
        --stride 1 --stride 5 --stride 10 [--frames A:B] [--weights W] [--device cpu]

prints end-point drift, per-pair RMSE, and how often each start won, per stride and variant.
"""

from __future__ import annotations

import warnings
from collections import Counter
from pathlib import Path

from rich.console import Console
from rich.table import Table
from sequence_args import sequence_parser


def main() -> None:
    parser = sequence_parser(__doc__)
    parser.add_argument("--stride", type=int, action="append", help="repeatable; default 1")
    parser.add_argument("--weights", type=Path, default=None)
    parser.add_argument("--device", default="auto")
    args = parser.parse_args()
    warnings.simplefilter("ignore")

    from vcr_odom.data import open_sequence
    from vcr_odom.data.selection import select_frames
    from vcr_odom.metrics import evaluate
    from vcr_odom.odometry import IcpPolish, KissIcpPolish, Odometry, build_odometry, run_odometry
    from vcr_odom.odometry.outputs import ground_truth_for

    sequence = open_sequence(args.seq, data_root=args.data_root)
    registrar = build_odometry("vcr+icp", weights=args.weights, device=args.device).registrar
    table = Table(title=f"{sequence.name}: VCR + polish, with and without the motion-prior start")
    for column in ("stride", "polish", "starts", "end-point [%]", "rot RMSE [deg]", "trans RMSE [m]", "won"):
        table.add_column(column, justify="right" if column != "polish" else "left")
    for stride in args.stride or [1]:
        indices = select_frames(len(sequence), args.frames, stride)
        gt = ground_truth_for(sequence, indices)
        for refine in ("icp", "kiss-icp"):
            for both in (True, False):
                polish = (
                    IcpPolish(second_start=both) if refine == "icp" else KissIcpPolish(keep_prediction=both)
                )
                method = Odometry(registrar, polish)
                run = run_odometry(sequence, method, indices)
                report = evaluate(run.poses, gt)
                won = Counter(i.get("polish_start") for i in run.per_frame_info[1:])
                table.add_row(
                    str(stride),
                    refine,
                    "global + prior" if both else "global only",
                    f"{report.endpoint.trans_error_percent:.2f}",
                    f"{report.pairs.rot_rmse_deg:.3f}",
                    f"{report.pairs.trans_rmse_m:.3f}",
                    ", ".join(f"{name} {count}" for name, count in sorted(won.items())),
                )
    Console(width=140).print(table)


if __name__ == "__main__":
    main()
