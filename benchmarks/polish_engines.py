"""The default odometry with each registration engine of its polish (``--polish-engine``), side by side.

Not a test: run

    .venv/bin/python benchmarks/polish_engines.py --sequence WORK/synth/sequences/701 [--sequence ...] \
        [--engine kiss-icp --engine vgicp] [--variant "vgicp, no finish=engine:vgicp,point_to_plane:off"] \
        [--frames A:B] [--stride K] [--repeat 1] [--json out.json] [--markdown]

``--variant NAME=option:value,...`` adds a row of other polish options (``point_to_plane:on|off``,
``engine:NAME``). Each sequence runs once per engine (and variant) and round (``--repeat N``: N
interleaved rounds, the frames/s a median), in this process one after the other, so the speed column
is a ratio to the first row's in the same run. Accuracy (end-point drift, SE(3)-aligned ATE) is the
same in every round: the runs are deterministic. *asked %*: pairs on which the network ran.
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

from doubt_misses import run_one, score  # beside this script

from vcr_odom.data import open_sequence
from vcr_odom.data.selection import select_frames
from vcr_odom.odometry.chain import DoubtRule
from vcr_odom.odometry.engine_choice import AUTO, ENGINE_CHOICES, engine_for

VARIANT_OPTIONS = {"engine": list(ENGINE_CHOICES), "point_to_plane": ["on", "off"]}
"""The polish options a ``--variant`` may set, and the values each takes."""


def parse_variant(text: str) -> tuple[str, dict]:
    """``name=option:value,...`` -> the row's name and its polish options."""
    name, _, body = text.partition("=")
    options = {}
    for item in filter(None, body.split(",")):
        key, _, value = item.partition(":")
        if key not in VARIANT_OPTIONS:
            raise SystemExit(
                f"--variant {text!r}: unknown option {key!r}; options: {', '.join(VARIANT_OPTIONS)}"
            )
        if value not in VARIANT_OPTIONS[key]:
            raise SystemExit(f"--variant {text!r}: {key} takes {' or '.join(VARIANT_OPTIONS[key])}")
        options[key] = value == "on" if key == "point_to_plane" else value
    return name, options


def measure(
    sequence_folder: Path, variants: list[tuple[str, dict]], repeat: int, frames: str | None, stride: int
) -> list[dict]:
    sequence = open_sequence(folder=sequence_folder)
    indices = select_frames(len(sequence), frames, stride)
    gt = None if sequence.gt_poses is None else sequence.gt_poses[indices]
    rows: dict[str, dict] = {}
    for _ in range(repeat):
        for engine, options in variants:
            if options.get("engine") == AUTO:  # the engine the frames' times call for
                options = {**options, "engine": engine_for(AUTO, sequence.timestamps[indices])}
            result = run_one(sequence, indices, "vcr", "on-doubt", DoubtRule(), options)
            row = rows.setdefault(engine, {"fps": [], **score(result["poses"], gt)})
            row["chosen"] = options.get("engine", "kiss-icp")
            row["fps"].append(result["fps"])
            row["asked_pct"] = result["asked_pct"]
    base = statistics.median(rows[variants[0][0]]["fps"])
    return [
        {
            "sequence": sequence_folder.name
            + (f", stride {stride}" if stride > 1 else "")
            + (f", frames {frames}" if frames else ""),
            "engine": engine,
            **{key: value for key, value in row.items() if key != "fps"},
            "fps": statistics.median(row["fps"]),
            "speed_ratio": statistics.median(row["fps"]) / base,
        }
        for engine, row in rows.items()
    ]


def markdown(rows: list[dict]) -> str:
    lines = [
        "| sequence | engine | asked % | end-point % | ATE m (SE3) | frames/s | against the first |",
        "|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(
            f"| {row['sequence']} | {row['engine']} | {row['asked_pct']:.1f} | "
            f"{row.get('end_point_pct', float('nan')):.3f} | {row.get('ate_m', float('nan')):.4f} | "
            f"{row['fps']:.1f} | {row['speed_ratio']:.2f}x |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequence", type=Path, action="append", required=True, help="a sequence folder")
    parser.add_argument(
        "--engine", action="append", choices=list(ENGINE_CHOICES), help="default: every engine but auto"
    )
    parser.add_argument("--variant", action="append", default=[], help="NAME=option:value,...")
    parser.add_argument("--frames", help="A:B, a Python slice of the frames")
    parser.add_argument("--stride", type=int, default=1)
    parser.add_argument("--repeat", type=int, default=1)
    parser.add_argument("--json", type=Path)
    parser.add_argument("--markdown", action="store_true")
    args = parser.parse_args()
    engines = args.engine or [name for name in ENGINE_CHOICES if name != AUTO]
    variants = [(engine, {"engine": engine}) for engine in engines]
    variants += map(parse_variant, args.variant)
    rows = []
    for folder in args.sequence:
        rows += measure(folder, variants, args.repeat, args.frames, args.stride)
        print(json.dumps(rows[-len(variants) :]), flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    if args.markdown:
        print(markdown(rows))


if __name__ == "__main__":
    main()
