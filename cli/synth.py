"""``vcr-odom synth``: write a synthetic sequence (procedural street or indoor floor, ray-cast LiDAR scans)
in the KITTI layout."""

from __future__ import annotations

from pathlib import Path

import click

from vcr_odom.cli.config_options import config_options
from vcr_odom.cli.progress import EXIT_CODES_HELP, console, frame_progress
from vcr_odom.results import check_output_folder, note_kept
from vcr_odom.synth import (
    SCENES,
    SENSOR_MODELS,
    SEQUENCE_NAME,
    SynthConfig,
    SynthSequence,
    write_sequence,
)
from vcr_odom.synth.kitti_layout import check_replaceable


def _check_seq(ctx: click.Context, param: click.Parameter, value: str) -> str:
    if not SEQUENCE_NAME.match(value):
        raise click.BadParameter("use letters, digits, '-' or '_' (e.g. 00)", ctx=ctx, param=param)
    return value


@click.command("synth", epilog=EXIT_CODES_HELP)
@click.option(
    "--out",
    type=click.Path(path_type=Path, file_okay=False),
    required=True,
    help="Root of the KITTI layout to write (sequences/<seq>/..., poses/<seq>.txt).",
)
@click.option(
    "--seq",
    default="00",
    show_default=True,
    callback=_check_seq,
    help="Sequence id (folder name under sequences/).",
)
@config_options(SynthConfig, ("frames", "seed", "speed"))
@click.option(
    "--sensor",
    type=click.Choice(SENSOR_MODELS),
    default="hdl64",
    show_default=True,
    help="LiDAR model: hdl64 (KITTI's HDL-64E), hdl32 (HDL-32E), vlp16 (VLP-16), os128 (Ouster OS1-128), "
    "os0 (Ouster OS0-128: 128 beams over 90 deg, 0.3-50 m, for indoors), "
    "avia (Livox Avia-like forward rosette, 70x77 deg), mid360 (Livox Mid-360-like, 360x59 deg); "
    "avia and mid360 scan non-repetitive patterns.",
)
@click.option(
    "--height",
    type=click.FloatRange(min=0.3, max=5.0),
    default=None,
    help="Sensor height above the ground in m (default 1.73, KITTI's mounting; with --motion "
    "handheld, a hand height of 1.2-1.6 m drawn from the seed; at most 1.8 indoors).",
)
@click.option(
    "--scene",
    type=click.Choice(SCENES),
    default="suburban",
    show_default=True,
    help="Street style: suburban (town, suburbs, country roads), avenue (wide, medians, trees), "
    "highway (4-6 lanes, guard rails, long curves), oldtown (narrow lanes, houses at the curb, tight turns); "
    "or indoor: one floor of a building, a ring of corridors round a core of rooms (doors, niches, columns, "
    "clutter, a hall or two), walked with --motion handheld on --route loop or return.",
)
@click.option(
    "--stops/--no-stops",
    default=False,
    show_default=True,
    help="Start from rest and stop for a few seconds now and then (frames with zero motion).",
)
@click.option(
    "--rate-hz",
    type=click.FloatRange(min=1.0, max=50.0),
    default=10.0,
    show_default=True,
    help="Frames per second (times.txt and the motion between frames follow it), e.g. 2 for a 2 Hz scanner.",
)
@config_options(SynthConfig, ("route", "motion", "keyframes", "keyframe_angle", "thin"))
@click.option(
    "--force",
    is_flag=True,
    default=False,
    help="Replace sequences/<seq> and poses/<seq>.txt even where synth did not make them (a real "
    "dataset's scans and ground truth are lost). Without it synth writes only where nothing is, into "
    "an empty folder, or over a sequence it made itself (its synth.json).",
)
def synth(
    out: Path,
    seq: str,
    frames: int,
    seed: int,
    speed: float,
    sensor: str,
    height: float | None,
    scene: str,
    stops: bool,
    rate_hz: float,
    route: str,
    motion: str,
    keyframes: float | None,
    keyframe_angle: float,
    thin: float | None,
    force: bool,
) -> None:
    """Generate a synthetic LiDAR sequence with exact ground truth (the built-in data set).

    The sequence is written beside its place and renamed into it, so an interrupted synth over an
    existing sequence leaves the old or the new one, never a mix. It replaces only a sequence it made
    itself (its synth.json), unless --force. With --keyframes, --frames frames
    are generated and only the keyframes among them written (numbered from 0, with their own times
    and poses).
    """
    check_output_folder(out, "--out")
    check_replaceable(out / "sequences" / seq, out / "poses" / f"{seq}.txt", force=force)
    config = SynthConfig(
        frames=frames,
        seed=seed,
        speed=speed,
        sensor=sensor,
        height=height,
        scene=scene,
        stops=stops,
        frame_period=1.0 / rate_hz,
        route=route,
        motion=motion,
        keyframes=keyframes,
        keyframe_angle=keyframe_angle,
        thin=thin,
    )
    sequence = SynthSequence(config)
    try:
        with frame_progress(f"synth seed {seed}", len(sequence)) as advance:
            written = write_sequence(sequence, out, seq, progress=advance, force=force)
    except KeyboardInterrupt as stopped:
        target = Path(out) / "sequences" / seq
        note_kept(
            stopped,
            f"{target} was not written" + (" (the one there is unchanged)" if target.exists() else ""),
        )
        raise
    kept = f" (keyframes of {written.generated})" if written.frames != written.generated else ""
    console.print(
        f"Wrote {written.frames} frames{kept} to {written.seq_dir} and poses to {written.poses_file}"
    )
    what = "Walk" if written.motion == "handheld" else "Drive"
    where = f", route {written.route}" if written.route != "street" else ""
    console.print(
        f"{what}: {written.length:.1f} m in {written.duration:.1f} s "
        f"({written.frames / written.seconds:.1f} frames/s generated); "
        f"{written.sensor} at {written.height:.2f} m, {written.scene} scene{where}"
    )
