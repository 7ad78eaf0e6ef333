"""The experiments behind VCR-Net's motion bias: one figure per lead, for any weight files.

Not a test. Each lead of the bias (the network shrinking motion towards zero between scans metres apart)
gets its own measurement on the same frames, VCR alone, one pass:

- ``shift``: relative change of the encoder's features when the whole cloud is shifted by 5 and 20 m
  or turned by 30° about z (0 for features that depend on relative geometry only);
- ``far``: share of the network's N points beyond 40 m with the weights' own input range, and with
  the 80 m crop where that is not already the weights' own;
- ``range``: the gap sweep with the weights' input range and with the other crop (80 / 40 m);
- ``pointer``: the gap sweep with the soft pointer's learned temperature and with it divided by 64
  (each virtual point nearly its best candidate, not a blend drawn towards the target's middle);
- ``svd``: the gap sweep with the paper's single unweighted SVD, with 5 re-weighting rounds, and with
  the consensus start before them (each unless it is how the weights run);
- ``matches``: per gap, the share of key points whose virtual correspondence lies within 1 m of
  where the true motion puts them, over all pairs and over the pairs the estimate fails (> 2° or
  > 0.5 m). Few good matches on failed pairs means the features, not the pose head, are at fault.

    .venv/bin/python benchmarks/bias_leads.py --data-root ../shared/data/kitti-sample --seq 00 \\
        --frames 40:60 --weights weights/vcr-default.safetensors --gap 1 --gap 5 --gap 10

prints one markdown table per lead.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from sequence_args import sequence_parser

SHIFTS = (
    ("shift 5 m", (5.0, 0.0, 0.0), 0.0),
    ("shift 20 m", (14.0, 14.0, 0.5), 0.0),
    ("yaw 30°", (0.0,) * 3, 30.0),
)


_BARE_HEAD = {"robust_iterations": 0, "consensus_hypotheses": 0, "consensus_seeds": 0, "gated_rounds": 0}
SVD_VARIANTS: tuple[tuple[str, dict[str, int]], ...] = (
    ("paper's SVD", _BARE_HEAD),
    ("5 re-weighting rounds", _BARE_HEAD | {"robust_iterations": 5}),
    ("consensus start + 5 rounds", _BARE_HEAD | {"robust_iterations": 5, "consensus_hypotheses": 256}),
    (
        "+ 32 compatible seeds, 3 gated rounds",
        _BARE_HEAD
        | {"robust_iterations": 5, "consensus_hypotheses": 256, "consensus_seeds": 32, "gated_rounds": 3},
    ),
)
"""The pose head's variants, each step of it added in turn: (label, inference settings)."""


def vcr_variant(path: Path, label: str, **overrides: Any) -> Any:
    """A VCR registrar (one pass) whose inference-time settings are overridden (not its weights)."""
    from vcr_odom.registration import make_method

    method = make_method("vcr", weights=path, device="cpu", passes=1)
    method.use_inference_settings(**overrides)
    method.name = f"{path.stem} ({label})"
    return method


def feature_shift(method: Any, frames: list[np.ndarray]) -> dict[str, float]:
    """Mean relative feature change ‖f(moved) - f‖ / ‖f‖ over the frames, per motion of :data:`SHIFTS`."""
    import torch

    from vcr_odom.geometry import make_transform, rotation_from_euler_zyx

    changes: dict[str, list[float]] = {label: [] for label, _, _ in SHIFTS}
    with torch.inference_mode():
        for frame in frames:
            xyz = method.network_input(frame)
            base = method.model.encode(torch.as_tensor(xyz)[None])
            for label, shift, yaw in SHIFTS:
                motion = make_transform(rotation_from_euler_zyx(math.radians(yaw), 0.0, 0.0), shift)
                moved = (xyz.astype(np.float64) @ motion[:3, :3].T + motion[:3, 3]).astype(np.float32)
                features = method.model.encode(torch.as_tensor(moved)[None])
                changes[label].append(float((features - base).norm() / base.norm()))
    return {label: float(np.mean(values)) for label, values in changes.items()}


def far_share(method: Any, frames: list[np.ndarray], max_range: float) -> float:
    """Share of the network's points farther than 40 m from the sensor with an input crop of ``max_range``."""
    from vcr_odom.preprocess import network_preprocess_config, preprocess

    config = network_preprocess_config(method.config.with_changes(input_max_range=max_range))
    shares = [float((np.linalg.norm(preprocess(f, config)[:, :3], axis=1) > 40.0).mean()) for f in frames]
    return float(np.mean(shares))


MATCH_RADIUS_M = 1.0


def match_agreement(
    method: Any, sequence: Any, selection: list[int], gaps: list[int]
) -> list[tuple[int, int, float, int, float]]:
    """Per gap: (gap, pairs, share of good matches, failed pairs, share of good matches on them)."""
    import torch

    from vcr_odom.evaluation.gap_sweep import gap_pairs, true_motions
    from vcr_odom.geometry import rotation_angle

    gt = np.asarray(sequence.gt_poses, dtype=np.float64)
    frames = {i: method.prepare(sequence.frame(i)) for i in selection}
    rows = []
    for gap in gaps:
        pairs = gap_pairs(selection, gap)
        shares, failed_shares = [], []
        for (target, source), truth in zip(pairs, true_motions(gt, pairs), strict=True):
            with torch.inference_mode():
                out = method.model.register_features(
                    frames[source].points,
                    frames[source].features,
                    frames[target].points,
                    frames[target].features,
                    source_attended=frames[source].attended,
                    target_attended=frames[target].attended,
                )
            key = out.key_points[0].double().numpy()
            virtual = out.virtual_points[0].double().numpy()
            share = float(
                np.mean(
                    np.linalg.norm(key @ truth[:3, :3].T + truth[:3, 3] - virtual, axis=1) < MATCH_RADIUS_M
                )
            )
            shares.append(share)
            error = np.linalg.inv(truth) @ out.transform[0].double().numpy()
            if np.degrees(rotation_angle(error)) > 2.0 or np.linalg.norm(error[:3, 3]) > 0.5:
                failed_shares.append(share)
        mean_failed = float(np.mean(failed_shares)) if failed_shares else math.nan
        rows.append((gap, len(pairs), float(np.mean(shares)), len(failed_shares), mean_failed))
    return rows


def main() -> None:
    parser = sequence_parser(__doc__)
    parser.add_argument("--weights", type=Path, action="append", default=[], help="VCR weights (repeat)")
    parser.add_argument("--gap", type=int, action="append", default=[], help="frames apart (repeat)")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    import torch

    torch.set_num_threads(1)
    from vcr_odom.data import open_sequence
    from vcr_odom.data.selection import select_frames
    from vcr_odom.evaluation.gap_sweep import markdown_table, run_gap_sweep
    from vcr_odom.model.weights import default_weights_path

    sequence = open_sequence(args.seq, data_root=args.data_root)
    selection = select_frames(len(sequence), args.frames)
    raw = [sequence.frame(i) for i in selection]
    gaps = args.gap or [1, 5, 10]
    for path in args.weights or [default_weights_path("default")]:
        own = vcr_variant(path, "as trained")
        print(
            f"\n## {path.name}: encoder {own.config.encoder}, input range {own.config.input_max_range:g} m, "
            f"{own.config.robust_iterations} robust rounds, {own.config.consensus_hypotheses} consensus "
            f"hypotheses, {own.config.consensus_seeds} compatible seeds, {own.config.gated_rounds} gated "
            f"rounds, pointer sharpened x{own.config.inference_sharpening:g}\n"
        )
        print("| feature change | " + " | ".join(label for label, _, _ in SHIFTS) + " |")
        print("|---|" + "---|" * len(SHIFTS))
        shifts = feature_shift(own, raw)
        print(
            "| relative ‖Δf‖ / ‖f‖ | " + " | ".join(f"{shifts[label]:.2e}" for label, _, _ in SHIFTS) + " |"
        )
        own_far = f"{100 * far_share(own, raw, own.config.input_max_range):.1f} % with the weights' "
        own_far += f"{own.config.input_max_range:g} m crop"
        if own.config.input_max_range != 80.0:
            own_far += f", {100 * far_share(own, raw, 80.0):.1f} % with 80 m"
        print(f"\npoints beyond 40 m: {own_far}\n")
        other_range = 40.0 if own.config.input_max_range > 40.0 else 80.0
        variants = [own, vcr_variant(path, f"{other_range:g} m crop", input_max_range=other_range)]
        other_sharpening = 1.0 if own.config.inference_sharpening != 1.0 else 64.0
        label = "soft pointer" if other_sharpening == 1.0 else "pointer sharpened x64"
        variants.append(vcr_variant(path, label, inference_sharpening=other_sharpening))
        for label, settings in SVD_VARIANTS:
            if any(getattr(own.config, name) != value for name, value in settings.items()):
                variants.append(vcr_variant(path, label, **settings))
        print(markdown_table(run_gap_sweep(sequence, selection, variants, gaps)))
        print(
            f"\n| gap | pairs | matches within {MATCH_RADIUS_M:g} m of the truth | failed pairs | their matches |"
        )
        print("|---:|---:|---:|---:|---:|")
        for gap, pairs, share, failed, failed_share in match_agreement(own, sequence, selection, gaps):
            failed_text = "-" if math.isnan(failed_share) else f"{100 * failed_share:.1f} %"
            print(f"| {gap} | {pairs} | {100 * share:.1f} % | {failed} | {failed_text} |")


if __name__ == "__main__":
    main()
