"""Options shared by several commands, and the error boundary between the library and the terminal."""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click
from click.core import ParameterSource

from vcr_odom.data.bin_scans import DEFAULT_BIN_COLUMNS, MAX_BIN_COLUMNS
from vcr_odom.data.kiss_loaders import LOADERS, install_hint, installed_loaders
from vcr_odom.data.selection import FrameSelection
from vcr_odom.errors import VcrOdomError

F = TypeVar("F", bound=Callable[..., Any])


class FriendlyGroup(click.Group):
    """The one exit-code convention (``vcr_odom.cli.progress``): the library's own errors become one
    clear line instead of a traceback, exit 2 for a ``ConfigError`` (a bad option, as click's own
    usage errors) and 1 for the rest; Ctrl-C that reaches here exits 130 (SIGTERM 143, SIGHUP 129:
    what was done is kept)."""

    def invoke(self, ctx: click.Context) -> Any:
        from vcr_odom.cli.progress import EXIT_USAGE, exit_interrupted, interrupt_label
        from vcr_odom.errors import ConfigError

        try:
            return super().invoke(ctx)
        except VcrOdomError as error:
            failure = click.ClickException(str(error))
            if isinstance(error, ConfigError):
                failure.exit_code = EXIT_USAGE
            raise failure from error
        except KeyboardInterrupt as stopped:
            note = getattr(stopped, "kept_note", "")
            exit_interrupted(f"Interrupted ({interrupt_label()}){f'; {note}' if note else ''}.")


def describe_loaders() -> str:
    """``--dataloader`` help: what is usable on this installation, and the extra for the rest."""
    installed = installed_loaders()
    missing = [f"{name} ({install_hint(name)})" for name in LOADERS if name not in installed]
    text = "Read --data with one of kiss-icp's loaders. Installed here: " + "; ".join(
        f"{name} ({LOADERS[name].summary})" for name in installed
    )
    return text + (f". Not installed: {'; '.join(missing)}." if missing else ".")


def sequence_options(function: F) -> F:
    """Where the frames come from (a KITTI-layout root plus ``--seq``, a plain ``--folder`` of scans, or
    a recording through ``--dataloader NAME --data PATH``) and which to use; the command receives them as
    one ``selection: FrameSelection`` argument."""
    decorators = [
        click.option(
            "--data-root",
            type=click.Path(path_type=Path),
            envvar="VCR_ODOM_DATA_ROOT",
            show_envvar=True,
            help="KITTI odometry root holding sequences/XX/velodyne and poses/XX.txt.",
        ),
        click.option(
            "--seq",
            default="00",
            show_default=True,
            help="Sequence id under --data-root (also the sequence of --dataloader kitti_raw, nuscenes, helipr).",
        ),
        click.option(
            "--folder",
            type=click.Path(path_type=Path, exists=True, file_okay=False),
            help="A plain folder of .bin/.pcd/.ply scans instead of --data-root/--seq.",
        ),
        click.option(
            "--poses",
            type=click.Path(path_type=Path, exists=True, dir_okay=False),
            help="With --folder or --dataloader: ground-truth poses (KITTI format, one line per frame).",
        ),
        click.option(
            "--calib",
            type=click.Path(path_type=Path, exists=True, dir_okay=False),
            help="With --poses: KITTI calib.txt whose Tr says the poses are in the camera frame.",
        ),
        click.option(
            "--times",
            type=click.Path(path_type=Path, exists=True, dir_okay=False),
            help="With --folder or --dataloader: timestamps, seconds, one line per frame (times.txt format). "
            "A times.txt inside --folder is used without this; with neither, 10 Hz is assumed (a warning).",
        ),
        click.option(
            "--bin-columns",
            type=click.IntRange(min=3, max=MAX_BIN_COLUMNS),
            default=DEFAULT_BIN_COLUMNS,
            show_default=True,
            help="float32 values per point in .bin scans: 4 = x, y, z, reflectance (KITTI); "
            "5 = x, y, z, intensity, ring; 3 = x, y, z. Columns past the 4th are ignored.",
        ),
        click.option(
            "--dataloader",
            type=click.Choice(list(LOADERS), case_sensitive=False),
            help=describe_loaders(),
        ),
        click.option(
            "--data",
            type=click.Path(path_type=Path, exists=True),
            help="With --dataloader: the recording (a .bag/.mcap/.pcap file, a ROS 2 bag folder, a dataset root).",
        ),
        click.option(
            "--topic",
            help="With --dataloader rosbag/mcap: the PointCloud2 or Livox CustomMsg topic (needed if several).",
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
        names = (
            "data_root",
            "seq",
            "folder",
            "poses",
            "calib",
            "times",
            "bin_columns",
            "dataloader",
            "data",
            "topic",
            "frames",
            "stride",
        )
        values = {name: kwargs.pop(name) for name in names}
        if _from_environment("data_root"):  # the library reads it and names the variable, not the option
            values["data_root"] = None
        kwargs["selection"] = FrameSelection(**values)
        return function(*args, **kwargs)

    for decorator in reversed(decorators):
        wrapper = decorator(wrapper)
    return wrapper  # type: ignore[return-value]


def _from_environment(name: str) -> bool:
    """Whether click took parameter ``name`` from its environment variable (so errors name that)."""
    context = click.get_current_context(silent=True)
    return context is not None and context.get_parameter_source(name) is ParameterSource.ENVIRONMENT


def results_dir_option(help: str) -> Callable[[F], F]:
    """``--results-dir``: one name for where results go, in every command that writes or reads them."""

    def decorate(function: F) -> F:
        return click.option(
            "--results-dir",
            type=click.Path(path_type=Path, file_okay=False),
            default=Path("results"),
            show_default=True,
            help=help,
        )(function)

    return decorate


results_option = results_dir_option("Where timestamped result folders (and a 'latest' link) are written.")


def initial_guess_option(function: F) -> F:
    return click.option(
        "--init",
        "initial_guess",
        type=click.Choice(["constant-velocity", "identity"]),
        default="constant-velocity",
        show_default=True,
        help="Initial guess of local (ICP) methods; global ones ignore it.",
    )(function)


def kiss_polish_options(function: F) -> F:
    """``--polish-voxel``, ``--point-to-plane`` and ``--polish-engine``: the kiss-icp polish's grid,
    its finish and what registers a frame to its map."""
    from vcr_odom.odometry.engine_choice import ENGINE_CHOICES

    function = click.option(
        "--polish-engine",
        type=click.Choice(list(ENGINE_CHOICES)),
        default="kiss-icp",
        show_default=True,
        help="What registers a frame to the kiss-icp polish's map: "
        + "; ".join(f"{name}: {text}" for name, text in ENGINE_CHOICES.items()),
    )(function)
    function = click.option(
        "--point-to-plane",
        type=click.Choice(["auto", "on", "off"]),
        default="auto",
        show_default=True,
        help="Finish the kiss-icp polish's fits point to plane: auto where the first frame is a raw "
        "sparse scan (solid-state; not spinning rings, not grid-thinned keyframes), where kiss-icp's "
        "point-to-point fit slides back towards standing still, and never with --polish-engine vgicp; "
        "on: always; off: never (docs/usage.md).",
    )(function)
    return click.option(
        "--polish-voxel",
        type=click.FloatRange(min=0.02),
        default=None,
        help="The kiss-icp polish's map voxel [m] for the whole run, instead of the one chosen from "
        "the first frame's density and reach (docs/usage.md).",
    )(function)


def describe_methods() -> str:
    """The method list for a command's epilog (click keeps \\b blocks unwrapped)."""
    from vcr_odom.odometry.factory import DEFAULT_CONSULT, DEFAULT_GLOBAL_POLISH, GLOBAL_METHODS
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
        + f"\n\b\nSo the default, vcr (vcr+{DEFAULT_GLOBAL_POLISH}, --consult {DEFAULT_CONSULT}), is kiss-icp's "
        "registration\nfrom its own prediction, with VCR-Net asked only where that result is in doubt; its "
        "estimate\nis then a second start (--consult every-frame: on every pair)."
    )


def vcr_options(function: F) -> F:
    """``--weights``, ``--device``, ``--vcr-passes`` and ``--vcr-points`` for the learned method (refused
    for the others), and ``--consult`` for any polished global method."""
    from vcr_odom.model.weights import MAX_NETWORK_POINTS
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
        "--vcr-points",
        type=click.IntRange(min=4, max=MAX_NETWORK_POINTS),
        default=None,
        help="Points VCR-Net is fed per scan. Default: the weights' own (1024 for the shipped file, "
        "trained on 512): 512 takes about a third of the network's time and misses more motions ~10 m long.",
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
