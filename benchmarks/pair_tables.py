"""The model card's pair tables: every row on the same pairs, including rows `compare` cannot build.

Not a test. `compare --protocol pairs` builds methods by name with default options; this harness adds
FPFH with a descriptor radius tuned for sparse clouds, and any number of VCR weight files, each with
one and with two network passes:

    .venv/bin/python benchmarks/pair_tables.py --data-root ../shared/data/kitti-sample --seq 00 \\
        --frames 40:60 --weights weights/vcr-default.safetensors \\
        --weights weights/legacy/vcr-default-xyz.safetensors

prints one markdown table per pair kind (same-scan, consecutive).
"""

from __future__ import annotations

import warnings
from pathlib import Path

from sequence_args import sequence_parser


def main() -> None:
    parser = sequence_parser(__doc__)
    parser.add_argument(
        "--points",
        type=int,
        default=None,
        help="points per cloud (default: the first VCR weights' N, else 512)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--weights", type=Path, action="append", default=[], help="VCR weights (repeat)")
    parser.add_argument("--fpfh-radius-factor", type=float, default=10.0, help="the tuned FPFH row")
    args = parser.parse_args()
    warnings.simplefilter("ignore")

    from vcr_odom.data import open_sequence
    from vcr_odom.data.selection import select_frames
    from vcr_odom.evaluation.pairs import evaluate_pair_protocol, pair_sets
    from vcr_odom.evaluation.pairs_polish import PolishedRegistrar, SparseIcp
    from vcr_odom.model.weights import read_weights
    from vcr_odom.odometry.factory import POLISHED_VCR_PASSES
    from vcr_odom.registration import make_method

    sequence = open_sequence(args.seq, data_root=args.data_root)
    frames = select_frames(len(sequence), args.frames)

    def tuned_fpfh():
        method = make_method("fpfh", feature_radius_factor=args.fpfh_radius_factor)
        return method.with_changes(name=f"fpfh(r x{args.fpfh_radius_factor:g})")

    def vcr(path: Path, passes: int):
        method = make_method("vcr", weights=path, device="cpu", passes=passes)
        method.name = f"vcr ({path.stem}, {passes} pass{'es' if passes > 1 else ''})"
        return method

    # Every row sees the clouds the (first) VCR weights run on: their input range and point count (a
    # cloud of fewer points would reach the network with repeated points, which its kNN graphs never saw).
    first = read_weights(args.weights[0])[1] if args.weights else None
    crop = first.input_max_range if first else 80.0
    points = args.points or (first.num_points if first else 512)
    for kind, pairs in pair_sets(sequence, frames, points, args.seed, max_range=crop).items():
        methods = ["icp10", "fpfh", tuned_fpfh(), *[vcr(w, p) for w in args.weights for p in (1, 2)]]
        methods += [PolishedRegistrar(tuned_fpfh(), SparseIcp())]
        # As compare's vcr+icp: one network pass before the polish (POLISHED_VCR_PASSES).
        methods += [PolishedRegistrar(vcr(w, POLISHED_VCR_PASSES), SparseIcp()) for w in args.weights]
        results = evaluate_pair_protocol(methods, pairs)
        print(f"\n{kind}: {len(pairs)} pairs of {points} points, frames {frames[0]}-{frames[-1]}\n")
        print("| method | rot RMSE / MAE [deg] | trans RMSE / MAE [m] | success | ms / pair |")
        print("|---|---|---|---|---|")
        for name, result in results.items():
            e = result.errors
            print(
                f"| {name} | {e.rot_rmse_deg:.3f} / {e.rot_mae_deg:.3f} | {e.trans_rmse_m:.3f} / "
                f"{e.trans_mae_m:.3f} | {100 * e.success_rate:.0f} % | {result.ms_per_pair_mean:.1f} |"
            )


if __name__ == "__main__":
    main()
