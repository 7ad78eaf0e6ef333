"""``vcr-odom cache``, ``vcr-odom pretrain`` and ``vcr-odom train``: VCR-Net's training commands.

Each command parses its options and calls one function of :mod:`vcr_odom.training.commands`; the
options of a configuration field are generated from it (:mod:`vcr_odom.cli.config_options`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

import click
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from vcr_odom.cli.config_options import config_options
from vcr_odom.cli.options import _from_environment
from vcr_odom.cli.progress import console
from vcr_odom.errors import ConfigError
from vcr_odom.model.config import PRESETS, VcrConfig
from vcr_odom.model.weights import MAX_NETWORK_POINTS
from vcr_odom.settings import Settings
from vcr_odom.training import (
    FrameSource,
    ProgressEvent,
    TrainConfig,
    TrainingData,
    cache_sequence,
    fit_on,
)

F = TypeVar("F", bound=Callable[..., Any])
S = TypeVar("S", bound=Settings)

SOURCE = ("data_root", "seqs", "copies", "frames", "stride")
DATA = ("caches", "protocols", "augment", "augment_yaw", "max_motion", "reverse", "val_fraction")
TRAINING = ("epochs", "batch_size", "lr", "seed", "device", "out", "checkpoint_every")
OBJECTIVE = ("objective", "counterpart_radius", "overlap_weight", "pose_weight", "correspondence_weight")
NAMES = {"seqs": "--seq", "caches": "--cache", "protocols": "--protocol"}
EXTRA: dict[str, dict[str, Any]] = {
    "data_root": {"envvar": "VCR_ODOM_DATA_ROOT", "show_envvar": True},
    "caches": {"type": click.Path(path_type=Path, exists=True, dir_okay=False)},
    "out": {"type": click.Path(path_type=Path, file_okay=False)},
    "init_weights": {"type": click.Path(path_type=Path, exists=True, dir_okay=False)},
}


def _source_options(function: F) -> F:
    function = config_options(FrameSource, SOURCE[2:], NAMES, EXTRA)(function)
    function = click.option(
        "--preset",
        type=click.Choice(sorted(PRESETS)),
        default="default",
        show_default=True,
        help="Model configuration (sets the number of points per cloud).",
    )(function)
    function = click.option(
        "--input-max-range",
        type=click.FloatRange(min=0.0, min_open=True),
        default=None,
        help="Metres of each scan the network sees (default: the preset's, 40 m). Cache and train at "
        "the crop the weights will run with: the shipped file runs with 80 m.",
    )(function)
    function = click.option(
        "--num-points",
        type=click.IntRange(min=4, max=MAX_NETWORK_POINTS),
        default=None,
        help="Points per cloud (default: the preset's, 512 for default). The shipped file was trained on "
        "512 and runs on 1024; cache and train with the same value.",
    )(function)
    return config_options(FrameSource, SOURCE[:2], NAMES, EXTRA)(function)


def _model_config(options: dict[str, Any]) -> VcrConfig:
    """The preset, with ``--input-max-range`` and ``--num-points`` where given."""
    config = VcrConfig.preset(options["preset"])
    changes = {
        name: options[name] for name in ("input_max_range", "num_points") if options.get(name) is not None
    }
    try:
        return config.with_changes(**changes)
    except ConfigError as error:
        raise click.UsageError(str(error)) from error


def _training_options(function: F) -> F:
    function = config_options(TrainConfig, ("select_on",), NAMES, EXTRA)(function)
    function = click.option("--resume", is_flag=True, help="Continue from OUT/last.pt.")(function)
    function = config_options(TrainConfig, TRAINING, NAMES, EXTRA)(function)
    function = config_options(TrainingData, DATA, NAMES, EXTRA)(function)
    return _source_options(function)


def _settings(kind: type[S], options: dict[str, Any], names: tuple[str, ...]) -> S:
    """``kind`` from the options of its fields; a bad combination is a usage error, like a bad option.
    A data root from ``$VCR_ODOM_DATA_ROOT`` is passed as none: the library reads the variable itself and
    names it, not ``--data-root``, when the root is bad."""
    values = {name: options[name] for name in names if name in options}
    if "data_root" in values and _from_environment("data_root"):
        values["data_root"] = None
    try:
        return kind(**values)
    except ConfigError as error:
        raise click.UsageError(str(error)) from error


@click.command("cache")
@_source_options
@click.option(
    "--out",
    type=click.Path(path_type=Path, dir_okay=False),
    required=True,
    help="The .npz file to write (one sequence: give one --seq).",
)
def cache(out: Path, **options: Any) -> None:
    """Ground-remove and down-sample a sequence once into a compact training cache (.npz)."""
    if len(options["seqs"]) != 1:
        raise click.BadParameter("give exactly one --seq per cache file", param_hint="--seq")
    source = _settings(FrameSource, options, SOURCE)
    with _progress() as (frames, _):
        built = cache_sequence(source, _model_config(options), out, progress=frames)
    console.print(f"{len(built.frame_indices)} frames x {source.copies} copies written to {out}")


@click.command("train")
@_training_options
@config_options(TrainConfig, ("init_weights", *OBJECTIVE), NAMES, EXTRA)
def train_command(**options: Any) -> None:
    """Train VCR-Net (correspondence loss; model chosen on the validation frames, never on test)."""
    _run("train", options)


@click.command("pretrain")
@_training_options
def pretrain_command(**options: Any) -> None:
    """Self-supervised pre-training of the encoder with the triplet loss (the paper's Algorithm 1)."""
    _run("pretrain", options)


def _run(task: str, options: dict[str, Any]) -> None:
    data = _settings(TrainingData, options, SOURCE + DATA)
    config = _settings(TrainConfig, options, (*TRAINING, "select_on", "init_weights", *OBJECTIVE))
    with _progress(" + ".join(data.protocols)) as (frames, events):
        result = fit_on(
            task,
            data,
            _model_config(options),
            config,
            resume=options["resume"],
            progress=events,
            frames_progress=frames,
        )
    if int(os.environ.get("RANK", "0")) == 0:  # under torchrun every rank gets here; rank 0 wrote the file
        console.print(
            f"best epoch {result.best_epoch + 1} (score {result.best_score:.4g}): {result.best_path}"
        )


@contextmanager
def _progress(
    protocols: str = "",
) -> Iterator[tuple[Callable[[str, int, int], None], Callable[[ProgressEvent], None]]]:
    """One bar per pre-processed sequence and per epoch; each finished epoch prints its validation
    figures. Yields the two callbacks: frames (name, done, total) and training events."""
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[loss]}"),
        TimeElapsedColumn(),
    )
    with Progress(*columns, console=console) as progress:
        bars: dict[Any, Any] = {}

        def on_frames(name: str, done: int, total: int) -> None:
            if name not in bars:
                bars[name] = progress.add_task(f"pre-processing {name}", total=total, loss="")
            progress.update(bars[name], completed=done)

        def on_event(event: ProgressEvent) -> None:
            if event.kind == "start":
                train, val = event.metrics["train_pairs"], event.metrics["val_pairs"]
                progress.console.print(f"{train} training and {val} validation pairs ({protocols})")
            elif event.kind == "step":
                if event.epoch not in bars:
                    bars[event.epoch] = progress.add_task(
                        f"{event.task} epoch {event.epoch + 1}/{event.epochs}", total=event.steps, loss=""
                    )
                loss = event.metrics.get("loss")
                progress.update(
                    bars[event.epoch],
                    completed=event.step,
                    loss=f"loss {loss:.4f}" if loss is not None else "",
                )
            elif event.kind == "epoch":
                shown = {
                    k: v for k, v in event.metrics.items() if k.startswith("val_") and isinstance(v, float)
                }
                progress.console.print(
                    f"epoch {event.epoch + 1}: " + ", ".join(f"{k} {v:.4g}" for k, v in sorted(shown.items()))
                )

        yield on_frames, on_event
