"""How a benchmark suite's wall time scales with where its cells run: docs/scaling.md's table.

    .venv/bin/python benchmarks/suite_scaling.py WORK_DIR [--datasets 16] [--frames 20] \
        [--config jobs:1 --config jobs:2 --config ray:1 --config ray:2] [--markdown table.md]

Writes ``--datasets`` synthetic drives (seeds 901...; HDL-64E, suburban) under WORK_DIR/synth and a
suite of them x methods icp10, kiss-icp x strides 1, 2 (64 cells by default), then runs that suite once
per configuration into a fresh folder: ``jobs:N`` a process pool of N, ``ray:N`` a local Ray cluster of N
CPUs. Per configuration: wall time, cells/s, the speed-up over the first configuration, the cells' own
time (summed from their metrics.json); and whether every configuration gave the same rows as the
first (figures to 1e-6; speed and folder names aside). The table goes to stdout, progress to stderr.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path
from typing import Any

from vcr_odom.suite.suite import run_suite
from vcr_odom.synth import generate_sequence

METHODS = ("icp10", "kiss-icp")
STRIDES = (1, 2)


def make_suite(work: Path, datasets: int, frames: int) -> Path:
    synth = work / "synth"
    for k in range(datasets):
        seq = f"{k:02d}"
        if not (synth / "poses" / f"{seq}.txt").is_file():
            generate_sequence(synth, seq=seq, frames=frames, seed=901 + k)
    lines = [f"methods = {json.dumps(list(METHODS))}", f"strides = {json.dumps(list(STRIDES))}"]
    for k in range(datasets):
        lines += ["[[dataset]]", f'name = "d{k:02d}"', f'data_root = "{synth}"', f'seq = "{k:02d}"']
    path = work / "suite.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def cell_seconds(folder: Path, rows: list[dict[str, Any]]) -> float:
    """The cells' own wall time (odometry loop) from their metrics.json."""
    total = 0.0
    for row in rows:
        metrics = json.loads((folder / row["folder"] / "metrics.json").read_text())
        total += metrics["run"]["wall_seconds"]
    return total


def figures(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [{k: v for k, v in row.items() if k not in ("fps", "folder")} for row in rows]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("work", type=Path)
    parser.add_argument("--datasets", type=int, default=16)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--config", action="append", default=[], help="jobs:N or ray:N (repeatable)")
    parser.add_argument("--markdown", type=Path)
    args = parser.parse_args()
    configs = args.config or ["jobs:1", "jobs:2", "ray:1", "ray:2"]
    suite = make_suite(args.work, args.datasets, args.frames)
    results = []
    for config in configs:
        kind, _, count = config.partition(":")
        if kind not in ("jobs", "ray") or not count.isdigit():
            parser.error(f"--config: jobs:N or ray:N; got {config!r}")
        out = args.work / f"out-{kind}{count}"
        shutil.rmtree(out, ignore_errors=True)
        started = time.perf_counter()
        outcome = run_suite(suite, out, jobs=int(count), ray="local" if kind == "ray" else None)
        wall = time.perf_counter() - started
        own = cell_seconds(out, outcome.rows)
        results.append((config, wall, own, outcome.rows))
        print(f"{config}: {wall:.1f} s for {len(outcome.rows)} cells", file=sys.stderr, flush=True)
    base_wall, base_rows = results[0][1], figures(results[0][3])
    lines = [
        "| where | cells | wall [s] | cells/s | speed-up | cells' own time [s] | same rows |",
        "|---|---|---|---|---|---|---|",
    ]
    for config, wall, own, rows in results:
        same = "yes" if figures(rows) == base_rows else "NO"
        lines.append(
            f"| {config.replace('jobs:', '--jobs ').replace('ray:', '--ray local --jobs ')} | {len(rows)} | "
            f"{wall:.1f} | {len(rows) / wall:.2f} | {base_wall / wall:.2f}x | {own:.1f} | {same} |"
        )
    table = "\n".join(lines) + "\n"
    print(table)
    if args.markdown:
        args.markdown.write_text(table)


if __name__ == "__main__":
    main()
