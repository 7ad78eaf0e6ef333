"""``vcr-odom view RESULT_FOLDER``: a finished result in 3-D (a window, or a picture off-screen)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import click

from vcr_odom.cli.progress import EXIT_CODES_HELP, console

if TYPE_CHECKING:
    from vcr_odom.map_command import MapOutcome
    from vcr_odom.odometry.run import RunOutcome
    from vcr_odom.viewer.live import LiveView

SIZE_HELP = "Picture size in pixels, WIDTHxHEIGHT (the window's size with a display)."


def parse_size(ctx: click.Context, param: click.Parameter, value: str) -> tuple[int, int]:
    """``1280x720`` -> (1280, 720); a usage error naming the option otherwise."""
    try:
        width, height = (int(part) for part in value.lower().split("x"))
    except ValueError:
        raise click.BadParameter(f"{value!r}: expected WIDTHxHEIGHT, e.g. 1280x720", ctx, param) from None
    if not (64 <= width <= 8192 and 64 <= height <= 8192):
        raise click.BadParameter(f"{value!r}: width and height must be 64 to 8192 pixels", ctx, param)
    return width, height


def screenshot_option(function: click.decorators.FC) -> click.decorators.FC:
    """``--screenshot FILE.png`` and ``--size``: render off-screen (no display needed) and write it."""
    function = click.option(
        "--size", metavar="WxH", default="1280x720", show_default=True, callback=parse_size, help=SIZE_HELP
    )(function)
    return click.option(
        "--screenshot",
        type=click.Path(path_type=Path, dir_okay=False),
        default=None,
        help="Render off-screen (no display needed: EGL) and write the picture to this .png instead of "
        "opening a window.",
    )(function)


@click.command("view", epilog=EXIT_CODES_HELP)
@click.argument("result_folder", type=click.Path(path_type=Path, file_okay=False))
@click.option(
    "--gt",
    type=click.Path(path_type=Path, dir_okay=False, exists=True),
    default=None,
    help="Ground-truth poses (KITTI format, every frame of the data; camera-frame where the run was "
    "calibrated). Default: the ground truth of the data the run read, where it still opens.",
)
@click.option(
    "--calib",
    type=click.Path(path_type=Path, dir_okay=False, exists=True),
    default=None,
    help="KITTI calib.txt for camera-frame trajectory files, where the one the run read has moved.",
)
@click.option(
    "--rejected",
    is_flag=True,
    default=False,
    help="Also draw the rejected loop candidates, one colour per reason (loops.json's failed_check).",
)
@click.option("--no-map", "with_map", flag_value=False, default=True, help="Leave map.ply out.")
@screenshot_option
def view(
    result_folder: Path,
    gt: Path | None,
    calib: Path | None,
    rejected: bool,
    with_map: bool,
    screenshot: Path | None,
    size: tuple[int, int],
) -> None:
    """Show a result folder of run or map in 3-D: the estimated and ground-truth trajectories, the
    odometry's beside a map's, map.ply, accepted loops as arcs between their frames (--rejected: the
    rejected candidates too, coloured by why) and the flagged frames.

    Needs the viz extra (pip install 'vcr-odom[viz]'): a window where there is a display, or
    --screenshot FILE.png off-screen.
    """
    from vcr_odom.viewer.result import draw_result, read_result
    from vcr_odom.viewer.scene import Scene, check_screenshot_path

    check_screenshot_path(screenshot)
    width, height = size
    scene = Scene(headless=screenshot is not None, width=width, height=height)
    data = read_result(result_folder, gt=gt, calib=calib, with_map=with_map)
    for note in data.notes:
        console.print(f"[yellow]{note}")
    legend = draw_result(scene, data, rejected=rejected, width=width, height=height)
    console.print(describe(data, rejected))
    if screenshot is not None:
        scene.screenshot(screenshot, legend)
        console.print(f"picture written to {screenshot}")
    else:
        scene.show()


def describe(data: object, rejected: bool) -> str:
    """One line saying what was drawn (what a picture alone cannot say: the counts)."""
    from vcr_odom.viewer.result import ResultData

    assert isinstance(data, ResultData)
    parts = [f"{len(data.poses)} poses"]
    if data.ground_truth is not None:
        parts.append("ground truth")
    if data.odometry is not None:
        parts.append("the odometry")
    if data.map_points is not None:
        parts.append(f"map of {len(data.map_points)} points ({data.map_file})")
    accepted = sum(loop.accepted for loop in data.loops)
    left = len(data.loops) - accepted
    if data.loops:
        parts.append(f"{accepted} accepted loop(s)")
        if left:
            parts.append(f"{left} rejected candidate(s)" + ("" if rejected else " (--rejected draws them)"))
    if data.flagged_frames:
        parts.append(f"{len(data.flagged_frames)} flagged frame(s)")
    return f"{data.folder}: " + ", ".join(parts)


# -- run|map --visualize -------------------------------------------------------------------------------


def visualize_options(function: click.decorators.FC) -> click.decorators.FC:
    """``--visualize`` (with ``--screenshot`` and ``--size``) for run and map."""
    function = screenshot_option(function)
    return click.option(
        "--visualize",
        is_flag=True,
        default=False,
        help="Show the run in 3-D as it goes: the scan, the local map, the trajectory, the frames where "
        "the network was asked or a motion was flagged (pip install 'vcr-odom[viz]'). With --screenshot "
        "FILE.png it renders off-screen and writes the end of the run there.",
    )(function)


@dataclass(frozen=True)
class LiveOptions:
    """What ``--visualize``, ``--screenshot`` and ``--size`` asked for."""

    screenshot: Path | None
    width: int
    height: int


def pop_live_options(ctx: click.Context, options: dict[str, object]) -> LiveOptions | None:
    """Take the view's options out of ``options`` (the command's settings do not know them); None
    without ``--visualize``."""
    visualize = bool(options.pop("visualize"))
    screenshot = options.pop("screenshot")
    size = options.pop("size")
    assert (screenshot is None or isinstance(screenshot, Path)) and isinstance(size, tuple)
    if not visualize:
        if screenshot is not None:
            raise click.UsageError(
                "--screenshot goes with --visualize (the picture is of the live view)", ctx=ctx
            )
        return None
    return LiveOptions(screenshot, int(size[0]), int(size[1]))


def open_live_view(options: LiveOptions | None, *, mapping: bool = False) -> LiveView | None:
    """The live view, opened before any work, so that a missing extra or display is one line then
    and not after the run; None without ``--visualize``."""
    if options is None:
        return None
    from vcr_odom.viewer.live import LiveView
    from vcr_odom.viewer.result import ESTIMATE, ODOMETRY

    trajectory = ("odometry", ODOMETRY) if mapping else ("trajectory", ESTIMATE)
    return LiveView(options.screenshot, width=options.width, height=options.height, trajectory=trajectory)


def finish_live_view(live: LiveView | None, outcome: RunOutcome | MapOutcome) -> None:
    """After run or map: exact markers from the run's records, the ground truth, and for a map its
    optimised trajectory and loops; then the picture, or the window until it is closed."""
    if live is None:
        return
    from vcr_odom.map_command import MapOutcome
    from vcr_odom.odometry.outputs import ground_truth_for
    from vcr_odom.viewer.result import read_result

    run = outcome.odometry if isinstance(outcome, MapOutcome) else outcome.run
    if not run.frame_indices:
        return
    live.mark(run.frame_indices, run.per_frame_info)
    truth = ground_truth_for(outcome.sequence, run.frame_indices)
    if truth is not None:
        live.show_ground_truth(truth)
    if isinstance(outcome, MapOutcome) and outcome.folder is not None and not run.interrupted:
        live.show_map(read_result(outcome.folder, with_map=False, with_ground_truth=False))
    picture = live.finish()
    if picture is not None:
        console.print(f"picture of the live view written to {picture}")
