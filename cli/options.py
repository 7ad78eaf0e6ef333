"""Options shared by several commands, and the error boundary between the library and the terminal."""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click

from vcr_odom.data.selection import FrameSelection
from vcr_odom.errors import VcrOdomError

F = TypeVar("F", bound=Callable[..., Any])


class FriendlyGroup(click.Group):
    """Turns the library's own errors into one clear line and exit code 1, instead of a traceback."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except VcrOdomError as error:
            raise click.ClickException(str(error)) from error


def sequence_options(function: F) -> F:
    """Where the frames come from (a KITTI-layout root plus ``--seq``, or a plain ``--folder`` of scans)
    and which to use; the command receives them as one ``selection: FrameSelection`` argument."""
    decorators = [
        click.option(
            "--data-root",
            type=click.Path(path_type=Path),
            envvar="VCR_ODOM_DATA_ROOT",
            show_envvar=True,
            help="KITTI odometry root holding sequences/XX/velodyne and poses/XX.txt.",
        ),
        click.option("--seq", default="00", show_default=True, help="Sequence id under --data-root."),
        click.option(
            "--folder",
            type=click.Path(path_type=Path, exists=True, file_okay=False),
            help="A plain folder of .bin/.pcd/.ply scans instead of --data-root/--seq.",
        ),
        click.option(
            "--poses",
            type=click.Path(path_type=Path, exists=True, dir_okay=False),
            help="With --folder: ground-truth poses (KITTI format).",
        ),
        click.option(
            "--calib",
            type=click.Path(path_type=Path, exists=True, dir_okay=False),
            help="With --folder: KITTI calib.txt whose Tr says the poses are in the camera frame.",
        ),
        click.option("--frames", default=None, metavar="A:B", help="Only frames A..B-1 (Python slice)."),
        click.option(
            "--stride",
            type=click.IntRange(min=1),
            default=1,
            show_default=True,
            help="Use every K-th frame (larger motion between frames).",
        ),
    ]

    @functools.wraps(function)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        names = ("data_root", "seq", "folder", "poses", "calib", "frames", "stride")
        kwargs["selection"] = FrameSelection(**{name: kwargs.pop(name) for name in names})
        return function(*args, **kwargs)

    for decorator in reversed(decorators):
        wrapper = decorator(wrapper)
    return wrapper  # type: ignore[return-value]


def results_option(function: F) -> F:
    return click.option(
        "--results-dir",
        type=click.Path(path_type=Path, file_okay=False),
        default=Path("results"),
        show_default=True,
        help="Where timestamped result folders (and a 'latest' link) are written.",
    )(function)


def initial_guess_option(function: F) -> F:
    return click.option(
        "--init",
        "initial_guess",
        type=click.Choice(["constant-velocity", "identity"]),
        default="constant-velocity",
        show_default=True,
        help="Initial guess of local (ICP) methods; global ones ignore it.",
    )(function)


def describe_methods() -> str:
    """The method list for a command's epilog (click keeps \\b blocks unwrapped)."""
    from vcr_odom.odometry.factory import DEFAULT_GLOBAL_POLISH, GLOBAL_METHODS
    from vcr_odom.odometry.polish import POLISHES
    from vcr_odom.registration import METHOD_NAMES

    lines = [f"  {name:<10} {text}" for name, text in METHOD_NAMES.items()]
    polish = [f"  +{name:<9} {text}" for name, text in POLISHES.items()]
    return (
        "\b\nMethods:\n"
        + "\n".join(lines)
        + "\n\b\nPolish of a pairwise method (NAME+POLISH; "
        + f"{', '.join(GLOBAL_METHODS)} get +{DEFAULT_GLOBAL_POLISH} unless told, the others +none):\n"
        + "\n".join(polish)
    )


def vcr_options(function: F) -> F:
    """``--weights``, ``--device`` and ``--vcr-passes`` for the learned method (ignored by the others),
    and ``--consult`` for any polished global method."""
    from vcr_odom.odometry.chain import CONSULT_CHOICES
    from vcr_odom.odometry.factory import DEFAULT_CONSULT

    function = click.option(
        "--consult",
        type=click.Choice(list(CONSULT_CHOICES)),
        default=DEFAULT_CONSULT,
        show_default=True,
        help="When a polished global method (vcr, fpfh) runs its registration: "
        + "; ".join(f"{name}: {text}" for name, text in CONSULT_CHOICES.items())
        + ".",
    )(function)
    function = click.option(
        "--vcr-passes",
        type=click.IntRange(min=1),
        default=None,
        help="VCR-Net passes per pair: each pass after the first registers the source moved by the "
        "estimate so far. Default: 1 (2 unpolished for legacy xyz-encoder weights, whose features "
        "change with the source's position; the invariant encoder's do not).",
    )(function)
    function = click.option(
        "--device",
        type=click.Choice(["auto", "cpu", "cuda"]),
        default="auto",
        show_default=True,
        help="Where VCR-Net runs (auto: CUDA when present).",
    )(function)
    return click.option(
        "--weights",
        type=click.Path(path_type=Path, exists=True, dir_okay=False),
        help="VCR-Net weights (.safetensors); default: the shipped weights/vcr-default.safetensors.",
    )(function)
