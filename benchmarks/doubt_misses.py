"""How often the default's doubt rule misses what asking the network on every frame catches.

A *miss* is a frame where the polished motion of ``METHOD@every-frame`` differs from the on-doubt
run's by more than 0.2 m or 1 deg (the issue's definition); every-frame is the reference because it
polishes from the network's start as well as the prior's on every pair. Each variant is a
``--variant NAME=field:value,...`` of :class:`vcr_odom.odometry.chain.DoubtRule` fields and the polish's
``adapt_voxel`` (``adapt_voxel:0``: kiss-icp's own voxel; ``default`` is the method as it ships);
``--baseline SPEC`` adds other methods' rows (accuracy and speed only). Not a test: run

    .venv/bin/python benchmarks/doubt_misses.py --sequence ../shared/data/kitti-sample/sequences/00 \
        --sequence runs/synth/sequences/101 [--frames A:B] [--stride K] [--method vcr+kiss-icp] \
        [--variant fit-only=correction_m:0,correction_deg:0] [--baseline kiss-icp] [--json out.json] \
        [--markdown table.md]

Per sequence and rule it prints the share of frames that asked the network, the misses, the
end-point drift and ATE against the ground truth, and frames/s in this process (indicative only:
``pipeline_speed.py`` measures speed).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
from rich.console import Console
from rich.table import Table

from vcr_odom.data import open_sequence
from vcr_odom.data.selection import select_frames
from vcr_odom.geometry import motion_difference
from vcr_odom.metrics.drift import endpoint_drift
from vcr_odom.metrics.evo_errors import ate_rpe
from vcr_odom.metrics.pairs import relative_motions
from vcr_odom.odometry import build_odometry, run_odometry
from vcr_odom.odometry.chain import DoubtRule, network_asked

MISS_M, MISS_DEG = 0.2, 1.0


POLISH_FIELDS = {"adapt_voxel": bool, "point_to_plane": bool, "coarse_start": bool}
"""Variant fields that go to the polish instead of the doubt rule (``adapt_voxel:0``: kiss-icp's voxel;
``point_to_plane:0``: no point-to-plane finish on sparse scans; ``coarse_start:0``: no coarse stage for
far starts)."""


def parse_variant(text: str) -> tuple[str, DoubtRule, dict[str, Any]]:
    """``name=field:value,field:value`` -> a DoubtRule with those fields changed from the default, and
    the polish options among them (:data:`POLISH_FIELDS`)."""
    name, _, body = text.partition("=")
    fields = {f.name: f.type for f in dataclasses.fields(DoubtRule)}
    changes: dict[str, Any] = {}
    polish: dict[str, Any] = {}
    for item in filter(None, body.split(",")):
        key, _, value = item.partition(":")
        if key in POLISH_FIELDS:
            polish[key] = POLISH_FIELDS[key](float(value))
        elif key in fields:
            kind = fields[key]
            changes[key] = (
                int(value)
                if kind in ("int", int)
                else bool(int(value))
                if kind in ("bool", bool)
                else float(value)
            )
        else:
            known = ", ".join([*fields, *POLISH_FIELDS])
            raise SystemExit(f"--variant {text!r}: unknown field {key!r}; fields: {known}")
    return name, dataclasses.replace(DoubtRule(), **changes), polish


def misses(reference: np.ndarray, candidate: np.ndarray) -> list[int]:
    """Frame indices (into the run) whose relative motion differs beyond the miss thresholds."""
    out = []
    for i, (a, b) in enumerate(zip(relative_motions(reference), relative_motions(candidate), strict=True)):
        change_m, change_deg = motion_difference(a, b)
        if change_m > MISS_M or change_deg > MISS_DEG:
            out.append(i + 1)
    return out


def score(poses: np.ndarray, gt: np.ndarray | None) -> dict[str, float]:
    if gt is None:
        return {}
    end = endpoint_drift(poses, gt)
    return {
        "end_point_pct": end.trans_error_percent,
        "ate_m": ate_rpe(poses, gt, alignment="se3").ate_trans_rmse_m,
    }


def run_one(
    sequence: Any,
    indices: list[int],
    spec: str,
    consult: str | None,
    doubt: DoubtRule | None,
    polish: dict[str, Any] | None = None,
) -> dict:
    options: dict[str, Any] = {} if consult is None else {"consult": consult, "doubt": doubt}
    if polish:
        options["polish_options"] = polish
    method = build_odometry(spec, **options)
    run = run_odometry(sequence, method, indices)
    asked = ["global" not in info or network_asked(info) for info in run.per_frame_info[1:]]
    return {
        "poses": run.poses,
        "asked_pct": 100.0 * float(np.mean(asked)) if asked else 0.0,
        "fps": run.frames_per_second,
        "reasons": [info.get("global") for info in run.per_frame_info],
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--sequence", type=Path, action="append", required=True, help="a sequences/XX folder")
    parser.add_argument("--frames", default=None)
    parser.add_argument("--stride", type=int, default=1)
    parser.add_argument("--method", default="vcr+kiss-icp")
    parser.add_argument("--variant", action="append", default=[], help="NAME=field:value,... of DoubtRule")
    parser.add_argument("--baseline", action="append", default=[], help="another method's row, e.g. kiss-icp")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--markdown", type=Path, help="also write the table here as markdown")
    parser.add_argument("--label", default="", help="prefix of each row's sequence name (e.g. the stride)")
    args = parser.parse_args()
    variants = [("default", DoubtRule(), {}), *map(parse_variant, args.variant)]
    table = Table(title=f"{args.method}: on-doubt rules against every-frame (stride {args.stride})")
    for column in ("sequence", "rule", "asked %", "misses", "end-point %", "ATE m (SE3)", "frames/s"):
        table.add_column(column, justify="left" if column in ("sequence", "rule") else "right")
    rows = []
    for folder in args.sequence:
        sequence = open_sequence(folder=folder)
        indices = select_frames(len(sequence), args.frames, args.stride)
        gt = sequence.gt_poses
        gt = None if gt is None else gt[indices]
        reference = run_one(sequence, indices, args.method, "every-frame", None)
        results = [("every-frame", reference, [])]
        for name, rule, polish in variants:
            result = run_one(sequence, indices, args.method, "on-doubt", rule, polish)
            results.append((name, result, misses(reference["poses"], result["poses"])))
        for spec in args.baseline:
            results.append((spec, run_one(sequence, indices, spec, None, None), None))
        for name, result, missed in results:
            row = {
                "label": args.label,
                "sequence": str(folder),
                "rule": name,
                "asked_pct": result["asked_pct"] if missed is not None else None,
                "misses": len(missed) if missed is not None else None,
                "missed_frames": [indices[i] for i in missed] if missed is not None else None,
                "pairs": len(indices) - 1,
                "fps": result["fps"],
                **score(result["poses"], gt),
            }
            rows.append(row)
            table.add_row(*cells(row))
    Console().print(table)
    if args.json:
        args.json.write_text(json.dumps({"rows": rows}, indent=1))
    if args.markdown:
        header = [str(column.header) for column in table.columns]
        lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(cells(row)) + " |" for row in rows]
        args.markdown.write_text("\n".join(lines) + "\n")


def cells(row: dict[str, Any]) -> list[str]:
    """One table row: the sequence folder as ``parent/name``, figures at the printed precision."""
    folder = Path(row["sequence"])
    on_doubt = row["misses"] is not None
    name = f"{folder.parent.parent.name}/{folder.name}"
    return [
        f"{row['label']}: {name}" if row["label"] else name,
        row["rule"],
        f"{row['asked_pct']:.1f}" if on_doubt else "",
        f"{row['misses']}/{row['pairs']}" if on_doubt else "",
        f"{row.get('end_point_pct', float('nan')):.2f}",
        f"{row.get('ate_m', float('nan')):.3f}",
        f"{row['fps']:.1f}",
    ]


if __name__ == "__main__":
    main()
