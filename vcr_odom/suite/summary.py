"""What a suite folder says about all its cells: ``summary.json`` (one row per cell), ``summary.md``
(a table per dataset, the mean over datasets and the pooled devkit figure, both labelled) and plots.

Both averages are reported because both are in use: kiss-icp's evaluation averages each sequence's
drift (every sequence weighs the same), the KITTI devkit pools every segment of every sequence (a long
sequence weighs more). They differ, and a reader comparing with a paper must know which is which."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from vcr_odom.errors import VcrOdomError
from vcr_odom.geometry import camera_to_lidar_poses, normalise_to_first
from vcr_odom.io import atomic_write_text, read_kitti_poses
from vcr_odom.results import write_json

DEVKIT_LABEL = "KITTI devkit drift over segments of 100-800 m"
COLUMNS = (
    ("method", "method", "{}"),
    ("stride", "stride", "{}"),
    ("status", "status", "{}"),
    ("frames", "frames", "{}"),
    ("t_rel %", "t_rel_pct", "{:.2f}"),
    ("r_rel °/100 m", "r_rel_deg_per_100m", "{:.2f}"),
    ("ATE SE(3) [m]", "ate_m", "{:.3f}"),
    ("end-point %", "end_point_pct", "{:.2f}"),
    ("frames/s", "fps", "{:.1f}"),
)


def write_summary(suite_folder: Path, rows: Sequence[dict[str, Any]], suite_file: Path) -> None:
    """``summary.json`` and ``summary.md``, each written whole or not at all (after every cell)."""
    write_json(
        suite_folder / "summary.json",
        {
            "suite": str(suite_file),
            "written": datetime.now().isoformat(timespec="seconds"),
            "rows": list(rows),
        },
    )
    atomic_write_text(suite_folder / "summary.md", summary_markdown(rows, suite_file))


def format_cell(row: dict[str, Any], key: str, fmt: str) -> str:
    """A figure as the tables show it; '-' where there is none."""
    value = row.get(key)
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return fmt.format(value)


def _table(headers: Sequence[str], lines: Sequence[Sequence[str]]) -> list[str]:
    return ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)] + [
        "| " + " | ".join(line) + " |" for line in lines
    ]


def summary_markdown(rows: Sequence[dict[str, Any]], suite_file: Path) -> str:
    done = sum(row["status"] == "complete" for row in rows)
    out = [
        f"# Benchmark: {suite_file.name}",
        "",
        f"{done} of {len(rows)} cells complete. t_rel / r_rel: each cell's drift as `run` scores it "
        f"({DEVKIT_LABEL}, or shorter segments on a short sequence, named per cell in summary.json); "
        "ATE after an SE(3) alignment (as `evo_ape -a` and kiss-icp report it); end-point: % of the path.",
        "",
    ]
    for dataset in dict.fromkeys(row["dataset"] for row in rows):
        out += [f"## {dataset}", ""]
        mine = [row for row in rows if row["dataset"] == dataset]
        out += _table(
            [h for h, _, _ in COLUMNS], [[format_cell(r, k, f) for _, k, f in COLUMNS] for r in mine]
        )
        problems = [r for r in mine if r["status"] != "complete" and r.get("reason")]
        out += [""] + [
            f"- {r['method']} stride {r['stride']}: {r['status']}: {r['reason']}" for r in problems
        ]
        out += [""] if problems else []
    out += ["## Over datasets", "", *averages_markdown(rows)]
    return "\n".join(out) + "\n"


def averages(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per method and stride: the mean of the datasets' drift (kiss-icp's way) and the devkit's pooled
    drift (segments of every dataset together), over the complete cells; ``kitti_segments`` says whether
    all of them were scored on KITTI's 100-800 m segments (a short dataset is not)."""
    out = []
    for method, stride in dict.fromkeys((row["method"], row["stride"]) for row in rows):
        cells = [r for r in rows if r["method"] == method and r["stride"] == stride]
        scored = [r for r in cells if r["status"] == "complete" and r["t_rel_pct"] is not None]
        segments = sum(r["drift_segments"] or 0 for r in scored)
        out.append(
            {
                "method": method,
                "stride": stride,
                "datasets": len(scored),
                "of": len(cells),
                "mean_t_rel_pct": _mean([r["t_rel_pct"] for r in scored]),
                "mean_r_rel_deg_per_100m": _mean([r["r_rel_deg_per_100m"] for r in scored]),
                "pooled_t_rel_pct": _weighted([(r["t_rel_pct"], r["drift_segments"] or 0) for r in scored]),
                "pooled_r_rel_deg_per_100m": _weighted(
                    [(r["r_rel_deg_per_100m"], r["drift_segments"] or 0) for r in scored]
                ),
                "segments": segments,
                "kitti_segments": bool(scored) and all(r.get("drift_label") == DEVKIT_LABEL for r in scored),
            }
        )
    return out


def averages_markdown(rows: Sequence[dict[str, Any]]) -> list[str]:
    lines = [
        [
            a["method"],
            str(a["stride"]),
            f"{a['datasets']} of {a['of']}",
            format_cell(a, "mean_t_rel_pct", "{:.2f}"),
            format_cell(a, "mean_r_rel_deg_per_100m", "{:.2f}"),
            format_cell(a, "pooled_t_rel_pct", "{:.2f}"),
            format_cell(a, "pooled_r_rel_deg_per_100m", "{:.2f}"),
            "100-800 m (KITTI)" if a["kitti_segments"] else "shorter: not comparable with KITTI",
        ]
        for a in averages(rows)
    ]
    headers = [
        "method",
        "stride",
        "datasets",
        "mean t_rel % (per dataset)",
        "mean r_rel °/100 m",
        "pooled t_rel % (devkit)",
        "pooled r_rel °/100 m",
        "segments",
    ]
    note = (
        "Complete cells only. A dataset with under 100 m of path is scored on shorter segments; where "
        "one is, the row says so and its figures do not sit beside KITTI's. *Mean*: each dataset weighs the same, as "
        "kiss-icp averages its sequences; *pooled*: every segment of every dataset together, as the KITTI "
        "devkit scores a whole benchmark."
    )
    return [*_table(headers, lines), "", note]


def _mean(values: Sequence[float]) -> float | None:
    return float(np.mean(values)) if values else None


def _weighted(pairs: Sequence[tuple[float, int]]) -> float | None:
    total = sum(weight for _, weight in pairs)
    return float(sum(value * weight for value, weight in pairs) / total) if total else None


def write_plots(suite_folder: Path, rows: Sequence[dict[str, Any]], datasets: dict[str, Any]) -> list[Path]:
    """``plots/<dataset>.png`` (every method at the smallest stride over the ground truth) and
    ``plots/t_rel.png`` (drift per dataset and method). A dataset that cannot be opened here gets its
    overlay without ground truth, and without the trajectories written in its camera frame."""
    from vcr_odom.plots import plot_trajectories

    folder = suite_folder / "plots"
    folder.mkdir(exist_ok=True)
    written = []
    for name, entry in datasets.items():
        mine = [r for r in rows if r["dataset"] == name and r["folder"]]
        if not mine:
            continue
        stride = min(r["stride"] for r in mine)
        sequence = _open_quietly(entry, stride)
        trajectories, gt = {}, None
        for row in (r for r in mine if r["stride"] == stride):
            poses, frames = _lidar_trajectory(suite_folder / row["folder"], sequence)
            if poses is not None:
                trajectories[
                    f"{row['method']} ({row['status']})" if row["status"] != "complete" else row["method"]
                ] = poses
                if gt is None and sequence is not None and sequence.gt_poses is not None:
                    gt = normalise_to_first(sequence.gt_poses[frames])
        if trajectories:
            written.append(
                plot_trajectories(folder / f"{name}.png", trajectories, gt, title=f"{name}, stride {stride}")
            )
    scored = [r for r in rows if r["t_rel_pct"] is not None]
    if scored:
        written.append(_plot_drift(folder / "t_rel.png", scored))
    return written


def _open_quietly(entry: Any, stride: int) -> Any:
    try:
        return entry.selection(stride).open()
    except (VcrOdomError, OSError):
        return None


def _lidar_trajectory(folder: Path, sequence: Any) -> tuple[np.ndarray | None, list[int]]:
    """The attempt's poses in the LiDAR frame (its KITTI file is in the camera frame where calibrated)."""
    try:
        poses = read_kitti_poses(folder / "trajectory_kitti.txt")
        frames = json.loads((folder / "frames.json").read_text(encoding="utf-8"))
    except (OSError, ValueError, VcrOdomError):  # a partial attempt may hold nothing yet
        return None, []
    if frames.get("poses_frame") == "camera":
        if sequence is None or sequence.tr_velo_to_cam is None:
            return None, []
        poses = camera_to_lidar_poses(poses, sequence.tr_velo_to_cam)
    return poses, list(frames.get("frame_indices", []))


def _plot_drift(path: Path, rows: Sequence[dict[str, Any]]) -> Path:
    from vcr_odom.plots import plot_grouped_bars

    datasets = list(dict.fromkeys(r["dataset"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    value = {(r["dataset"], r["method"], r["stride"]): r["t_rel_pct"] for r in rows}
    panels = {
        f"stride {stride}": (
            datasets,
            {m: [value.get((d, m, stride), math.nan) for d in datasets] for m in methods},
        )
        for stride in sorted({r["stride"] for r in rows})
    }
    return plot_grouped_bars(path, panels, ylabel="t_rel [%]")
