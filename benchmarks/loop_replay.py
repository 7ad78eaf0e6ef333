"""The loop phase of ``vcr-odom map`` again on an odometry recorded once: what a change to the
candidates, the verification or the pose graph does, in a minute where the odometry takes many.
Not a test: run

    # once per sequence: the odometry as `map` runs it, with the nodes it records
    .venv/bin/python benchmarks/loop_replay.py record --sequence WORK/sequences/881 --out rec/881.pkl \
        [--stride K] [--method vcr] [--polish-voxel V] [--point-to-plane auto|on|off] \
        [--polish-engine kiss-icp|vgicp]
    # after each change under vcr_odom/loops: the loop phase on the recording, scored against the truth
    .venv/bin/python benchmarks/loop_replay.py replay rec/881.pkl [rec/898.pkl ...] [--json out.json] \
        [--set passage_attempts=1000 ...] [--candidates DIR]

A recording holds what ``map`` hands its loop phase: the nodes (odometry poses, coarse clouds), every
frame's pose, what the odometry said of each frame, and the loop options
(``--set NAME=VALUE`` replaces one of them, a field of ``LoopSettings``, for the replay; a recorded
option this checkout no longer has is left at its default). The
replay runs ``close_loops`` on it with the code of this checkout and scores it as
``benchmarks/loop_closure.py`` does (the same function): SE(3)-aligned ATE of the odometry and the map,
revisit passages closed, loops kept and the false ones (more than 1 m / 3 deg off the truth, each
listed with its frames; below the table, the right ones' RMS error over all the recordings, own-cloud
and submap fits apart), how far the map moved any frame, and the seconds of the candidates'
verification and of the graph (``loop_seconds``: compare a change's cost in one process on a quiet
machine; ``OMP_NUM_THREADS=1`` keeps two replays side by side from slowing each other many times
over). A change to the odometry or to how nodes are recorded needs a new recording.
``--candidates DIR`` writes, per recording, every candidate with its verdict (``failed_check``,
``reason``) and how far its measured transform and the odometry's are from the truth: a right loop
turned away, or a false one that passed, named with the check that decided it.

``replay --truth-loops`` runs the loop phase a second time with the graph given the truth's
``T_target_source`` for each loop it gets (the same loops, informations and rounds) and adds that
map's ATE (``truth_loops_map_ate_m``): where it is no better than the map's, the loops' measurements
are not what holds the map back, the odometry's shape between the places they tie is. It also splits
the odometry's error in what its per-step rotation errors and its per-step translation errors make
alone (``odometry_rotation_share``, ``odometry_error_split.py``): loops undo the first, not the second;
and gives the odometry's scale error (``odometry_scale_error``), which no loop sees.

Recordings are Python pickles of this checkout's classes: a cache for the machine that made them,
not a file to exchange (load only recordings you made; a recording from other code may not load).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pickle
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from loop_closure import candidates_against_truth, score_loops  # beside this script
from odometry_error_split import error_split  # beside this script
from rich.console import Console
from rich.table import Table

from vcr_odom.data.selection import FrameSelection
from vcr_odom.errors import ConfigError
from vcr_odom.geometry import invert
from vcr_odom.io import replacing
from vcr_odom.loops import pipeline
from vcr_odom.loops.nodes import NodeRecorder
from vcr_odom.loops.pipeline import Phases, close_loops, loop_network, loops_json
from vcr_odom.loops.settings import LoopSettings
from vcr_odom.map_command import MapSettings
from vcr_odom.metrics.evo_errors import ate_rpe
from vcr_odom.odometry.engine_choice import ENGINE_CHOICES
from vcr_odom.odometry.frame_loop import run_odometry
from vcr_odom.odometry.outputs import ground_truth_for
from vcr_odom.odometry.run import method_for

FORMAT = 1
"""Bumped when what a recording holds changes; a replay refuses other formats."""


def _commit() -> str:
    """The checkout's commit, so a recording says which odometry made it."""
    done = subprocess.run(
        ["git", "-C", str(Path(__file__).parent), "describe", "--always", "--dirty"],
        capture_output=True,
        text=True,
        check=False,
    )
    return done.stdout.strip() or "unknown"


def record(args: argparse.Namespace) -> None:
    folder: Path = args.sequence
    selection = FrameSelection(data_root=folder.parent.parent, seq=folder.name, stride=args.stride)
    settings = MapSettings(
        selection=selection,
        method=args.method,
        polish_voxel=args.polish_voxel,
        point_to_plane=args.point_to_plane,
        polish_engine=args.polish_engine,
        results_dir=Path("unused"),
    )
    sequence = selection.open()
    indices = selection.indices(sequence)
    odometry = method_for(settings, sequence.timestamps[indices])
    recorder = NodeRecorder(settings.node_spacing_m, settings.node_angle_deg)
    run = run_odometry(
        sequence, odometry, indices, on_frame=lambda i, pose, points: recorder(i, pose, points)
    )
    if run.interrupted or not run.frame_indices:
        raise SystemExit(
            f"{folder}: the odometry stopped ({run.interruption or 'interrupted'}); nothing recorded"
        )
    recording = {
        "format": FORMAT,
        "commit": _commit(),
        "sequence": str(folder.resolve()),
        "stride": args.stride,
        "method": args.method,
        "polish_voxel": args.polish_voxel,
        "point_to_plane": args.point_to_plane,
        "polish_engine": args.polish_engine,
        "network": {
            "weights": settings.weights,
            "device": settings.device,
            "vcr_points": settings.vcr_points,
        },
        "loop_options": {k: getattr(settings, k) for k in LoopSettings.model_fields},
        "nodes": recorder.finish(),
        "poses": run.poses,
        "frame_indices": list(run.frame_indices),
        "per_frame_info": run.per_frame_info,
    }
    with replacing(args.out) as temporary, temporary.open("wb") as handle:
        pickle.dump(recording, handle)
    print(f"{len(run.frame_indices)} frames, {len(recording['nodes'])} nodes -> {args.out}")


def load_recording(path: Path) -> tuple[dict[str, Any], np.ndarray]:
    """A recording of :func:`record` and its sequence's ground truth at the recorded frames; SystemExit
    naming the file where it is not one, or its sequence has no ground truth."""
    with path.open("rb") as handle:
        recording = pickle.load(handle)  # the caller's own recording (see the module doc)
    if not isinstance(recording, dict) or recording.get("format") != FORMAT:
        raise SystemExit(f"{path}: not a recording of format {FORMAT}; record it again with this checkout")
    folder = Path(recording["sequence"])
    selection = FrameSelection(data_root=folder.parent.parent, seq=folder.name, stride=recording["stride"])
    gt = ground_truth_for(selection.open(), recording["frame_indices"])
    if gt is None:
        raise SystemExit(f"{path}: {folder} has no ground truth to score against")
    return recording, gt


def recorded_options(recording: dict[str, Any]) -> dict[str, Any]:
    """The loop options the recording was made with that this checkout's :class:`LoopSettings` knows."""
    return {k: v for k, v in recording["loop_options"].items() if k in LoopSettings.model_fields}


def replay_one(
    path: Path,
    options_set: dict[str, str] | None = None,
    truth_loops: bool = False,
    candidates: Path | None = None,
) -> dict[str, Any]:
    """The loop phase on one recording, scored against its sequence's ground truth; ``options_set``
    replaces recorded loop options (``LoopSettings`` field names, values as typed); ``truth_loops``
    adds the map's ATE with every loop the graph gets measured by the truth (see the module doc);
    ``candidates``: a folder that gets ``<sequence>.json``, every candidate's verdict and its errors
    against the truth (:func:`candidates_against_truth`)."""
    recording, gt = load_recording(path)
    folder = Path(recording["sequence"])
    network = loop_network(
        recording["network"]["weights"], recording["network"]["device"], recording["network"]["vcr_points"]
    )
    options = LoopSettings(**(recorded_options(recording) | (options_set or {})))
    phases = Phases(None)
    closed = close_loops(options, network, recording["nodes"], recording["poses"], phases)
    loops = loops_json(closed.decisions, recording["nodes"])
    if candidates is not None:
        judged = candidates_against_truth(gt, recording["frame_indices"], loops)
        candidates.mkdir(parents=True, exist_ok=True)
        with replacing(candidates / f"{folder.name}.json") as temporary:
            temporary.write_text(json.dumps(judged, indent=1, default=_plain))
    row = score_loops(
        gt, recording["frame_indices"], loops, recording["poses"], closed.poses, options.min_loop_path_m
    )
    if truth_loops:
        with _loops_measured_by(gt, recording["nodes"]):
            ideal = close_loops(options, network, recording["nodes"], recording["poses"], Phases(None))
        row["truth_loops_map_ate_m"] = ate_rpe(ideal.poses, gt, alignment="se3").ate_trans_rmse_m
        split = error_split(recording["poses"], gt)
        row["odometry_rotation_only_ate_m"] = split.rotation_only_ate_m
        row["odometry_translation_only_ate_m"] = split.translation_only_ate_m
        row["odometry_rotation_share"] = split.rotation_share
        row["odometry_scale_error"] = split.scale_error
    return {
        "recording": str(path),
        "sequence": folder.name,
        "recorded_at": recording["commit"],
        "options_set": options_set or {},
        **row,
        "odometry_covariance_scale": closed.odometry_scale,
        "loop_seconds": phases.seconds,
    }


@contextmanager
def _loops_measured_by(gt: np.ndarray, nodes: list[Any]) -> Iterator[None]:
    """The loop phase's pose graph given ``gt``'s ``T_target_source`` (every frame's true pose) in
    place of each loop's measured one; everything else as the verification left it."""
    optimise = pipeline.optimise

    def with_true_loops(poses: Any, information: Any, loops: list[Any], *args: Any, **kwargs: Any) -> Any:
        true = [
            dataclasses.replace(
                loop, transform=invert(gt[nodes[loop.target].position]) @ gt[nodes[loop.source].position]
            )
            for loop in loops
        ]
        return optimise(poses, information, true, *args, **kwargs)

    pipeline.optimise = with_true_loops
    try:
        yield
    finally:
        pipeline.optimise = optimise


def replay(args: argparse.Namespace) -> None:
    rows = [replay_one(path, args.options_set, args.truth_loops, args.candidates) for path in args.recordings]
    table = Table(title=f"the loop phase at {_commit()} on recorded odometry")
    for header in (
        "sequence",
        "odometry ATE [m]",
        "map ATE [m]",
        "ratio",
        "passages closed",
        "loops (false)",
    ):
        table.add_column(header)
    table.add_column("false loops: frames, m / deg off (chi2 under its information)")
    if args.truth_loops:
        table.add_column("map ATE, loops measured by the truth [m]")
        table.add_column("odometry error's rotation share")
        table.add_column("odometry scale error [%]")
    table.add_column("max change [m]")
    table.add_column("loops / graph [s]")
    for row in rows:
        false = "; ".join(
            f"{a}->{b} {f['error_m']:.2f} / {f['error_deg']:.1f}"
            + ("" if f.get("error_chi2") is None else f" (chi2 {f['error_chi2']:.1f})")
            for f in row["false_closure_details"]
            for a, b in [f["frames"]]
        )
        table.add_row(
            row["sequence"],
            f"{row['odometry_ate_m']:.3f}",
            f"{row['map_ate_m']:.3f}",
            f"{row['ate_ratio']:.2f}",
            f"{row['passages_closed']}/{row['revisit_passages']}",
            f"{row['accepted']} ({row['false_closures']})",
            false or "-",
            *(
                [
                    f"{row['truth_loops_map_ate_m']:.3f}",
                    f"{row['odometry_rotation_share']:.2f}",
                    f"{100 * row['odometry_scale_error']:+.2f}",
                ]
                if args.truth_loops
                else []
            ),
            f"{row['max_change_m']:.3f}",
            f"{row['loop_seconds']['loops']:.1f} / {row['loop_seconds']['graph']:.1f}",
        )
    console = Console()
    console.print(table)
    for kind, (count, metres, degrees) in right_loop_errors(rows).items():
        console.print(f"right loops, {kind}: {count}, RMS error {metres:.3f} m / {degrees:.2f} deg")
    if args.json:
        with replacing(args.json) as temporary:
            temporary.write_text(json.dumps(rows, indent=1, default=_plain))


def right_loop_errors(rows: list[dict[str, Any]]) -> dict[str, tuple[int, float, float]]:
    """The right loops' errors against the truth (within the false-loop bound) pooled over ``rows``,
    own-cloud fits and submap fits apart: {kind: (loops, RMS m, RMS deg)}, kinds without a loop left
    out. Submap fits carry the odometry's bend over the submaps' path, which their sigmas do not."""
    pooled: dict[str, tuple[int, float, float]] = {}
    for kind, submaps in (("own clouds", False), ("submaps", True)):
        errors = [e for row in rows for e in row["right_loop_errors"] if e["submaps"] == submaps]
        if errors:
            metres = float(np.sqrt(np.mean([e["error_m"] ** 2 for e in errors])))
            degrees = float(np.sqrt(np.mean([e["error_deg"] ** 2 for e in errors])))
            pooled[kind] = (len(errors), metres, degrees)
    return pooled


def add_set_option(parser: argparse.ArgumentParser, what: str = "a loop setting") -> None:
    """``--set NAME=VALUE`` (repeatable): a field of ``LoopSettings``, checked by :func:`loop_options_set`."""
    parser.add_argument(
        "--set",
        dest="options_set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help=f"{what} (a LoopSettings field, e.g. passage_attempts=1000); repeatable",
    )


def loop_options_set(items: list[str], parser: argparse.ArgumentParser) -> dict[str, str]:
    """``--set`` items as {name: value}, each checked against ``LoopSettings`` now, not after the first
    recording has replayed."""
    chosen: dict[str, str] = {}
    for item in items:
        name, equals, value = item.partition("=")
        if not equals or name not in LoopSettings.model_fields:
            parser.error(
                f"--set {item}: expected NAME=VALUE with NAME one of {', '.join(LoopSettings.model_fields)}"
            )
        try:
            LoopSettings(**{name: value})
        except ConfigError as error:
            parser.error(f"--set {item}: {error}")
        chosen[name] = value
    return chosen


def _plain(value: Any) -> Any:
    return value.item() if isinstance(value, np.generic) else str(value)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    commands = parser.add_subparsers(dest="command", required=True)
    made = commands.add_parser("record", help="run map's odometry once and keep what its loop phase gets")
    made.add_argument("--sequence", type=Path, required=True, help="sequences/<id> folder")
    made.add_argument("--out", type=Path, required=True, help="the recording to write (.pkl)")
    made.add_argument("--stride", type=int, default=1)
    made.add_argument("--method", default="vcr")
    made.add_argument(
        "--polish-voxel", type=float, help="the kiss-icp polish's voxel [m] (map's --polish-voxel)"
    )
    made.add_argument(
        "--point-to-plane",
        choices=("auto", "on", "off"),
        default="auto",
        help="the polish's point-to-plane finish (map's --point-to-plane)",
    )
    made.add_argument(
        "--polish-engine",
        choices=list(ENGINE_CHOICES),
        default="kiss-icp",
        help="what registers a frame to the polish's map (map's --polish-engine)",
    )
    again = commands.add_parser("replay", help="the loop phase of this checkout on recordings")
    again.add_argument("recordings", type=Path, nargs="+")
    again.add_argument("--json", type=Path)
    add_set_option(again, "replace a recorded loop option")
    again.add_argument(
        "--candidates",
        type=Path,
        metavar="DIR",
        help="write DIR/<sequence>.json: every candidate's verdict and how far its measured transform and "
        "the odometry's are from the truth",
    )
    again.add_argument(
        "--truth-loops",
        action="store_true",
        help="also the map's ATE with each loop the graph gets measured by the truth (twice the time)",
    )
    args = parser.parse_args()
    if args.command == "replay":
        args.options_set = loop_options_set(args.options_set, parser)
    if args.command == "record":
        if args.polish_voxel is not None and not args.polish_voxel > 0:
            parser.error(f"--polish-voxel {args.polish_voxel}: expected a voxel above 0 m")
        record(args)
    else:
        replay(args)


if __name__ == "__main__":
    main()
