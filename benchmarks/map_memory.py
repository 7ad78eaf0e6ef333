"""Peak memory of ``vcr-odom map`` against the frames it maps: each count in a fresh process (so a
peak is that run's alone), read back from the folder's ``metrics.json``. Not a test: run

    .venv/bin/python benchmarks/map_memory.py --data-root runs/loops/synth --seq 810 \
        --frames 250 --frames 500 --frames 1000 [--json out.json]

Why: the loop closure keeps a small cloud per node, and the map is built from node scans at the end,
so memory should grow with the path driven by tens of KB a node, not with every scan.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path


def measure(data_root: Path, seq: str, frames: int, scratch: Path) -> dict[str, float]:
    results = scratch / f"f{frames}"
    command = [sys.executable, "-m", "vcr_odom.cli.main", "map", "--data-root", str(data_root)]
    command += ["--seq", seq, "--frames", f"0:{frames}", "--results-dir", str(results)]
    subprocess.run(command, check=True, capture_output=True)
    (folder,) = [p for p in results.iterdir() if p.name[:2] == "20"]
    memory = json.loads((folder / "metrics.json").read_text())["memory"]
    return {
        "frames": frames,
        "nodes": memory["nodes"],
        "node_mib": memory["node_bytes"] / 2**20,
        "map_points": memory["map_points"],
        "peak_rss_mib": memory["peak_rss_bytes"] / 2**20,
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--data-root", type=Path, required=True)
    parser.add_argument("--seq", required=True)
    parser.add_argument("--frames", type=int, action="append", required=True)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        rows = [measure(args.data_root, args.seq, n, Path(scratch)) for n in args.frames]
    print("| frames | nodes | node clouds [MiB] | map points | peak RSS [MiB] |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['frames']} | {r['nodes']} | {r['node_mib']:.1f} | {r['map_points']} | {r['peak_rss_mib']:.0f} |"
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
