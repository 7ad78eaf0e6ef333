"""``vcr-odom cache``, ``vcr-odom pretrain`` and ``vcr-odom train``: VCR-Net's training commands.

Pre-processing (open3d) runs once into a frame cache; training then needs only numpy and torch, so
a cache built here can be carried to a GPU machine that has no open3d.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import click
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from vcr_odom.cli.progress import console
from vcr_odom.data import open_sequence
from vcr_odom.data.pairs import FrameCache, PairConfig, build_frame_cache, train_val_datasets
from vcr_odom.model.config import VcrConfig
from vcr_odom.odometry import select_frames
from vcr_odom.preprocess import network_preprocess_config
from vcr_odom.train import DEVICES, ProgressEvent, TrainConfig, pretrain, train

F = Callable[..., Any]


def _cache_source_options(function: F) -> F:
    for decorator in reversed(
        [
            click.option(
                "--data-root",
                type=click.Path(path_type=Path),
                envvar="VCR_ODOM_DATA_ROOT",
                show_envvar=True,
                help="KITTI-layout root (real or from `vcr-odom synth`).",
            ),
            click.option(
                "--seq", "seqs", multiple=True, help="Sequence id under --data-root; repeat for several."
            ),
            click.option(
                "--preset",
                type=click.Choice(["default", "paper"]),
                default="default",
                show_default=True,
                help="Model configuration (sets the number of points per cloud).",
            ),
            click.option(
                "--copies",
                type=click.IntRange(min=2),
                default=2,
                show_default=True,
                help="Independent down-samplings stored per frame.",
            ),
            click.option(
                "--frames",
                default=None,
                help="Only frames A:B of each --seq (B exclusive), e.g. to keep a test block out.",
            ),
            click.option(
                "--stride",
                type=click.IntRange(min=1),
                default=1,
                show_default=True,
                help="Every K-th frame of --frames (neighbouring frames are near-copies).",
            ),
        ]
    ):
        function = decorator(function)
    return function


@click.command("cache")
@_cache_source_options
@click.option(
    "--out",
    type=click.Path(path_type=Path, dir_okay=False),
    required=True,
    help="The .npz file to write (one sequence: give one --seq).",
)
def cache(
    data_root: Path | None,
    seqs: tuple[str, ...],
    preset: str,
    copies: int,
    frames: str | None,
    stride: int,
    out: Path,
) -> None:
    """Ground-remove and down-sample a sequence once into a compact training cache (.npz)."""
    if len(seqs) != 1:
        raise click.BadParameter("give exactly one --seq per cache file", param_hint="--seq")
    built = _build_cache(data_root, seqs[0], VcrConfig.preset(preset), copies, frames, stride)
    built.save(out)
    console.print(f"{len(built.frame_indices)} frames x {copies} copies written to {out}")


def _build_cache(
    data_root: Path | None, seq: str, model_config: VcrConfig, copies: int, frames: str | None, stride: int
) -> FrameCache:
    sequence = open_sequence(seq, data_root=data_root)
    indices = select_frames(len(sequence), frames, stride)
    config = PairConfig(
        num_points=model_config.num_points, preprocess=network_preprocess_config(model_config)
    )
    with _bar(f"pre-processing {sequence.name}", len(indices)) as advance:
        return build_frame_cache(
            sequence, indices, config=config, copies=copies, progress=lambda done, _: advance(done)
        )


def _training_options(function: F) -> F:
    for decorator in reversed(
        [
            _cache_source_options,
            click.option(
                "--cache",
                "caches",
                type=click.Path(path_type=Path, exists=True, dir_okay=False),
                multiple=True,
                help="Frame caches from `vcr-odom cache` (instead of, or beside, --seq).",
            ),
            click.option(
                "--protocol",
                "protocols",
                type=click.Choice(["odometry", "same-scan"]),
                multiple=True,
                help="Pairs of different scans with GT motion, or the paper's same-scan protocol (random "
                "yaw ±30°, tilt ±5°, ±5 m / ±1 m); repeat for both.  [default: odometry]",
            ),
            click.option(
                "--augment/--no-augment",
                default=True,
                show_default=True,
                help="Odometry pairs: add the same-scan random transform on top of the GT motion.",
            ),
            click.option(
                "--max-motion",
                type=click.FloatRange(min=0, min_open=True),
                default=None,
                help="Odometry pairs: every pair of frames at most this many metres apart (instead of "
                "pairs 1, 2, 3 and 5 frames apart).",
            ),
            click.option(
                "--reverse/--no-reverse",
                default=False,
                show_default=True,
                help="Odometry pairs: swap source and target of a random half of the pairs each epoch.",
            ),
            click.option(
                "--val-fraction",
                type=click.FloatRange(0.05, 0.5),
                default=0.2,
                show_default=True,
                help="Share of each sequence's frames (contiguous blocks) held out for validation.",
            ),
            click.option("--epochs", type=click.IntRange(min=1), default=30, show_default=True),
            click.option("--batch-size", type=click.IntRange(min=1), default=8, show_default=True),
            click.option(
                "--lr", type=click.FloatRange(min=0, min_open=True), default=1e-3, show_default=True
            ),
            click.option("--seed", type=int, default=0, show_default=True),
            click.option("--device", type=click.Choice(DEVICES), default="auto", show_default=True),
            click.option(
                "--out",
                type=click.Path(path_type=Path, file_okay=False),
                default=Path("runs/train"),
                show_default=True,
                help="Checkpoints (last.pt), best.safetensors, history.json.",
            ),
            click.option("--resume", is_flag=True, help="Continue from OUT/last.pt."),
            click.option(
                "--select-on",
                type=click.Choice(["loss", "rmse"]),
                default="loss",
                show_default=True,
                help="What picks best.safetensors: validation loss, or rotation RMSE / 1° + "
                "translation RMSE / 0.25 m.",
            ),
        ]
    ):
        function = decorator(function)
    return function


def _run_training(entry: Callable[..., Any], options: dict[str, Any], **extra: Any) -> None:
    model_config = VcrConfig.preset(options["preset"])
    caches = [FrameCache.load(path, num_points=model_config.num_points) for path in options["caches"]]
    caches += [
        _build_cache(
            options["data_root"], seq, model_config, options["copies"], options["frames"], options["stride"]
        )
        for seq in options["seqs"]
    ]
    if not caches:
        raise click.UsageError("give training data: --seq (with --data-root) or --cache")
    protocols = list(dict.fromkeys(options["protocols"] or ["odometry"]))
    pairs = [
        PairConfig(
            protocol=protocol,
            num_points=model_config.num_points,
            augment=options["augment"],
            seed=options["seed"],
            max_motion=options["max_motion"],
            reverse=options["reverse"],
        )
        for protocol in protocols
    ]
    train_set, val_set = train_val_datasets(caches, pairs, options["val_fraction"])
    console.print(f"{len(train_set)} training and {len(val_set)} validation pairs ({' + '.join(protocols)})")
    train_config = TrainConfig(
        epochs=options["epochs"],
        batch_size=options["batch_size"],
        lr=options["lr"],
        seed=options["seed"],
        device=options["device"],
        out=options["out"],
        select_on=options["select_on"],
        **extra,
    )
    with _training_bar() as on_event:
        result = entry(
            model_config, train_set, val_set, train_config, resume=options["resume"], progress=on_event
        )
    console.print(f"best epoch {result.best_epoch + 1} (score {result.best_score:.4g}): {result.best_path}")


@click.command("train")
@_training_options
@click.option(
    "--init-weights",
    type=click.Path(path_type=Path, exists=True, dir_okay=False),
    help="Start from these weights (e.g. pretrain's best.safetensors).",
)
def train_command(init_weights: Path | None, **options: Any) -> None:
    """Train VCR-Net (correspondence loss; model chosen on the validation frames, never on test)."""
    _run_training(train, options, init_weights=init_weights)


@click.command("pretrain")
@_training_options
def pretrain_command(**options: Any) -> None:
    """Self-supervised pre-training of the encoder with the triplet loss (the paper's Algorithm 1)."""
    _run_training(pretrain, options)


@contextmanager
def _bar(description: str, total: int) -> Iterator[Callable[[int], None]]:
    with Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
    ) as progress:
        task = progress.add_task(description, total=total)
        yield lambda done: progress.update(task, completed=done)


@contextmanager
def _training_bar() -> Iterator[Callable[[ProgressEvent], None]]:
    """One bar per epoch; each finished epoch prints its validation figures."""
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[loss]}"),
        TimeElapsedColumn(),
    )
    with Progress(*columns, console=console) as progress:
        tasks: dict[int, Any] = {}

        def on_event(event: ProgressEvent) -> None:
            if event.kind == "step":
                if event.epoch not in tasks:
                    tasks[event.epoch] = progress.add_task(
                        f"{event.task} epoch {event.epoch + 1}/{event.epochs}", total=event.steps, loss=""
                    )
                loss = event.metrics.get("loss")
                progress.update(
                    tasks[event.epoch],
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

        yield on_event
