"""Several methods on the same frames, side by side: what ``vcr-odom compare`` does, callable from Python.

The odometry protocol chains each method over the frames (one result sub-folder each); the pairs
protocol (:mod:`vcr_odom.evaluation.pairs`) registers isolated pairs. Nothing here prints: the caller
gets the outcomes and renders them.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from vcr_odom.data.base import LidarSequence
from vcr_odom.data.selection import FrameSelection
from vcr_odom.errors import ConfigError, MissingExtraError
from vcr_odom.evaluation.pairs import PAIR_KINDS, PairProtocolResult, evaluate_pair_protocol, pair_sets
from vcr_odom.evaluation.pairs_polish import PAIR_POLISHES
from vcr_odom.evaluation.rows import canonical_row, split_loops
from vcr_odom.loops.pipeline import loop_network
from vcr_odom.loops.settings import LoopSettings
from vcr_odom.map_command import map_and_save
from vcr_odom.metrics import EvaluationReport
from vcr_odom.model.weights import default_weights_path, read_weights
from vcr_odom.odometry.chain import Consult, Odometry
from vcr_odom.odometry.engine_choice import EngineChoice, engine_for
from vcr_odom.odometry.factory import DEFAULT_CONSULT, build_odometry, parse_method_spec
from vcr_odom.odometry.frame_loop import OdometryRun
from vcr_odom.odometry.limits import InitialGuess
from vcr_odom.odometry.outputs import ground_truth_for, run_summary
from vcr_odom.odometry.run import (
    ProgressFactory,
    kiss_polish_options,
    polish_flags,
    run_and_save,
    vcr_options,
)
from vcr_odom.plots import plot_trajectories
from vcr_odom.preprocess import PreprocessConfig
from vcr_odom.registration import SEQUENTIAL_METHODS
from vcr_odom.registration.base import SequentialOdometry
from vcr_odom.registration.vcr import VcrRegistrar
from vcr_odom.results import (
    check_output_folder,
    create_marked_folder,
    create_result_folder,
    deferred_interrupts,
    interruption_reason,
    note_kept,
    point_latest_at,
    remove_result_folder,
    result_unit,
    write_json,
    write_marker,
)
from vcr_odom.settings import Settings

DEFAULT_BASELINES = ("icp10", "icp", "fpfh", "kiss-icp")
PairKind = Literal["same-scan", "consecutive"]


class CompareSettings(Settings):
    """Everything ``vcr-odom compare`` is told; dumped as the result folder's ``config.json``.

    ``methods`` are specs as ``run`` spells them (``vcr`` is VCR-Net with its default polish,
    ``vcr+none`` VCR-Net alone). In the pairs protocol a spec's polish counts only where written out,
    and only ``+icp`` (on the pair's own clouds): kiss-icp needs a sequence's map.
    """

    selection: FrameSelection = FrameSelection()
    methods: tuple[str, ...] = DEFAULT_BASELINES
    protocol: Literal["odometry", "pairs", "both"] = "odometry"
    pair_points: int | None = Field(default=None, ge=64)
    pair_kinds: tuple[PairKind, ...] = PAIR_KINDS
    seed: int = 0
    initial_guess: InitialGuess = InitialGuess.CONSTANT_VELOCITY
    weights: Path | None = None
    device: str = "auto"
    vcr_passes: int | None = Field(default=None, ge=1)
    vcr_points: int | None = Field(default=None, ge=4)
    consult: Consult = DEFAULT_CONSULT
    polish_voxel: float | None = Field(default=None, gt=0)
    point_to_plane: Literal["auto", "on", "off"] = "auto"
    polish_engine: EngineChoice = "kiss-icp"
    results_dir: Path = Path("results")

    def method_options(self, spec: str) -> dict[str, Any]:
        method = spec.partition("+")[0].strip().lower()
        return vcr_options(method, self.weights, self.device, self.vcr_passes, self.vcr_points)

    def polish_options(self, spec: str, timestamps: NDArray[np.float64] | None = None) -> dict[str, object]:
        """``polish_voxel``, ``point_to_plane`` and ``polish_engine`` for a row with the kiss-icp polish
        (``auto`` chosen by the frames' ``timestamps``); none for the others (the kiss-icp baseline,
        kiss-slam and the other polishes keep their own)."""
        if parse_method_spec(spec)[1] != "kiss-icp":
            return {}
        engine = engine_for(self.polish_engine, timestamps)
        return kiss_polish_options(self.polish_voxel, self.point_to_plane, engine)


@dataclass
class MethodOutcome:
    """One row of the odometry comparison. ``status`` says why a row has no run (an optional method
    that is not installed: ``not installed: pip install 'vcr-odom[slam]'``); empty when it ran."""

    method: str
    needs_initial_guess: bool
    run: OdometryRun
    report: EvaluationReport | None
    status: str = ""


@dataclass(frozen=True)
class Unavailable:
    """A method that cannot run here (``error`` says why and what installs it): a row, not a failure."""

    error: MissingExtraError


@dataclass(frozen=True)
class Mapped:
    """A ``+loops`` row: ``odometry``, then ``vcr-odom map``'s loop closure with ``network``."""

    odometry: Odometry | SequentialOdometry
    network: VcrRegistrar


Method = Odometry | SequentialOdometry | Unavailable | Mapped


@dataclass
class Comparison:
    """What a comparison produced: the rows of each protocol and notes on what was left out.

    ``interrupted``: Ctrl-C (or SIGTERM, SIGHUP) stopped it: the rows hold what finished, and the
    method stopped in its odometry; the folder is marked partial.
    """

    folder: Path
    sequence: LidarSequence
    frame_indices: list[int]
    odometry: list[MethodOutcome] = field(default_factory=list)
    pairs: dict[str, dict[str, PairProtocolResult]] = field(default_factory=dict)
    pair_points: int = 0
    notes: list[str] = field(default_factory=list)
    interrupted: bool = False


def run_comparison(settings: CompareSettings, progress: ProgressFactory | None = None) -> Comparison:
    """One result folder; the odometry rows, the pairs tables, or both.

    Everything that can be wrong with the request (a method name, the output folder, a combination
    that would leave a protocol with nothing to do, unreadable weights) is found before the folder is
    made and any method runs. The folder's own unit (``compare.json``, ``pairs.json``, the overlay
    plot and the marker) is published at the end, or, stopped part-way, with a ``partial`` marker.
    """
    specs = list(dict.fromkeys(canonical_row(s) for s in settings.methods))  # a bad name fails here
    _check_polish_options(settings, specs)
    check_output_folder(settings.results_dir, "--results-dir")
    sequence = settings.selection.open()
    indices = settings.selection.indices(sequence)
    kinds = pair_kinds_to_run(settings, sequence) if settings.protocol != "odometry" else ()
    odometries: dict[str, Method] = {}
    if settings.protocol in ("odometry", "both"):
        odometries = {spec: _build(spec, settings, sequence.timestamps[indices]) for spec in specs}
        missing = [method.error for method in odometries.values() if isinstance(method, Unavailable)]
        if missing and len(missing) == len(odometries):
            raise ConfigError(f"nothing to compare: {missing[0]}")
    if kinds:
        pair_input_range([pair_spec(s) for s in settings.methods if works_on_pairs(s)], settings.weights)
    folder = create_result_folder(
        settings.results_dir,
        f"compare_{sequence.label}_stride{settings.selection.stride}",
        {"command": "compare", "sequence": sequence.name, **settings.to_dict()},
        frames_selected=len(indices),
    )
    comparison = Comparison(folder, sequence, indices)

    def method_done(outcomes: list[MethodOutcome]) -> None:  # a SIGKILL later still leaves it said
        comparison.odometry = outcomes
        publish_comparison(
            comparison,
            f"checkpoint after {len(outcomes)} of {len(odometries)} methods; the comparison was still "
            "going (if nothing newer replaced this, it was stopped or killed)",
        )

    try:
        if odometries:
            comparison.odometry = compare_methods(
                sequence, indices, folder, odometries, progress, method_done
            )
            comparison.interrupted = any(o.run.interrupted for o in comparison.odometry)
        if kinds and not comparison.interrupted:
            compare_pairs(settings, comparison, progress, kinds)
    except BaseException as error:
        with deferred_interrupts():  # a further interrupt waits until what finished is written
            if comparison.odometry or comparison.pairs:
                publish_comparison(comparison, interruption_reason(error))
                note_kept(error, f"what finished is kept in {folder} (result.json: partial)")
            else:
                remove_result_folder(folder)  # with the method's own partial folder: say so, whatever
                if isinstance(error, KeyboardInterrupt):  # that method's note said it kept
                    error.kept_note = "no method had finished; no result folder was kept"  # type: ignore[attr-defined]
        if isinstance(error, KeyboardInterrupt) and comparison.odometry:
            comparison.interrupted = True  # stopped inside a method (a +loops row's loop phase):
            return comparison  # the rows that finished are shown, as for a stop in the odometry
        raise
    stopped = next(
        (o.run.interruption or "interrupted" for o in comparison.odometry if o.run.interrupted), ""
    )
    with deferred_interrupts() if stopped else nullcontext():
        publish_comparison(comparison, stopped)
    return comparison


def _build(spec: str, settings: CompareSettings, timestamps: NDArray[np.float64]) -> Method:
    """The odometry called ``spec`` (with the loop network for a ``+loops`` row), or
    :class:`Unavailable` where it is an optional method that is not installed (its row says so; the
    other methods still run)."""
    base, mapped = split_loops(spec)
    try:
        odometry = build_odometry(
            base,
            initial_guess=settings.initial_guess,
            consult=settings.consult,
            polish_options=settings.polish_options(base, timestamps),
            **settings.method_options(base),
        )
    except MissingExtraError as error:
        return Unavailable(error)
    if not mapped:
        return odometry
    return Mapped(odometry, loop_network(settings.weights, settings.device, settings.vcr_points, odometry))


def _check_polish_options(settings: CompareSettings, specs: list[str]) -> None:
    """The kiss-icp polish's options with no row that has that polish would be ignored: a ConfigError
    (the CLI's usage error) naming them instead, before any folder is made."""
    given = polish_flags(
        kiss_polish_options(settings.polish_voxel, settings.point_to_plane, settings.polish_engine)
    )
    polished = [parse_method_spec(split_loops(spec)[0])[1] == "kiss-icp" for spec in specs]
    if given and not any(polished):
        raise ConfigError(
            f"{', '.join(given)} {'applies' if len(given) == 1 else 'apply'} to the kiss-icp polish, "
            f"and none of {', '.join(specs)} has it (the default of vcr and fpfh, or +kiss-icp)"
        )


def pair_kinds_to_run(settings: CompareSettings, sequence: LidarSequence) -> tuple[str, ...]:
    """The pair kinds the pairs protocol can score here; a ConfigError where it could score nothing
    (every method needs a map, or only consecutive pairs were asked for and there is no ground truth)."""
    if not any(works_on_pairs(spec) for spec in settings.methods):
        raise ConfigError(
            f"--protocol {settings.protocol}: none of the methods ({', '.join(settings.methods)}) works "
            "on isolated pairs (kiss-icp, as a method or a polish, and kiss-slam need a sequence's local map)"
        )
    kinds = tuple(settings.pair_kinds)
    if sequence.gt_poses is None and "consecutive" in kinds:
        if kinds == ("consecutive",):
            raise ConfigError(
                f"--pairs consecutive: {sequence.name} has no ground-truth poses to score them with; "
                "give --poses, or use --pairs same-scan"
            )
        kinds = tuple(k for k in kinds if k != "consecutive")
    return kinds


def compare_methods(
    sequence: LidarSequence,
    frame_indices: list[int],
    folder: Path,
    odometries: dict[str, Method],
    progress: ProgressFactory | None = None,
    method_done: Callable[[list[MethodOutcome]], None] | None = None,
) -> list[MethodOutcome]:
    """Each method over the same frames, one sub-folder each (itself a result unit, see
    :func:`~vcr_odom.odometry.run.run_and_save`, with a marker from the start). An
    :class:`Unavailable` method gets a row with its status and no folder. ``method_done(outcomes)``
    is called after each method that finished, before the next starts.

    Ctrl-C stops the method in progress and skips the rest; what finished is kept. ``latest`` moves to
    the comparison once its first method holds a trajectory.
    """
    outcomes: list[MethodOutcome] = []
    for spec, odometry in odometries.items():
        if isinstance(odometry, Unavailable):
            outcomes.append(MethodOutcome(spec, True, _no_run(spec), None, odometry.error.status))
            continue
        on_saved = partial(point_latest_at, folder.parent, folder)
        create_marked_folder(folder / spec, len(frame_indices))
        if isinstance(odometry, Mapped):
            mapped = map_and_save(
                sequence,
                odometry.odometry,
                odometry.network,
                frame_indices,
                folder / spec,
                LoopSettings(),
                progress=progress,
                on_saved=on_saved,
            )
            outcomes.append(
                MethodOutcome(spec, _needs_guess(odometry.odometry), mapped.mapped_run, mapped.report)
            )
            if mapped.odometry.interrupted:
                break
            if method_done is not None:
                method_done(outcomes)
            continue
        needs_guess = _needs_guess(odometry)
        with _progress(progress, spec, len(frame_indices)) as advance:
            run, report = run_and_save(
                sequence, odometry, frame_indices, folder / spec, progress=advance, on_saved=on_saved
            )
        outcomes.append(MethodOutcome(spec, needs_guess, run, report))
        if run.interrupted:
            break
        if method_done is not None:
            method_done(outcomes)
    return outcomes


def _needs_guess(odometry: Odometry | SequentialOdometry) -> bool:
    return odometry.registrar.needs_initial_guess if isinstance(odometry, Odometry) else True


def _no_run(spec: str) -> OdometryRun:
    return OdometryRun(spec, [], np.empty((0, 4, 4)), np.empty(0), {}, 0.0)


def publish_comparison(comparison: Comparison, reason: str = "") -> None:
    """The comparison's own unit: ``compare.json`` and the overlay plot (odometry rows), ``pairs.json``,
    then the marker, ``complete`` only when nothing stopped it."""
    folder, sequence, indices = comparison.folder, comparison.sequence, comparison.frame_indices
    rows = [o for o in comparison.odometry if not o.status]
    skipped = {o.method: o.status for o in comparison.odometry if o.status}
    done = max((len(o.run.frame_indices) for o in rows), default=0)  # a finished method: all of them
    with result_unit(folder) as unit:
        if rows:
            stride = indices[1] - indices[0] if len(indices) > 1 else 1
            plot_trajectories(
                unit / "trajectories.png",
                {o.method: o.run.poses for o in rows if len(o.run.poses)},
                ground_truth_for(sequence, indices),
                title=f"{sequence.name}, stride {stride}",
            )
            summary: dict[str, Any] = {
                o.method: {"run": run_summary(o.run), **(o.report.to_dict() if o.report else {})}
                for o in rows
            }
            summary.update({method: {"status": status} for method, status in skipped.items()})
            write_json(unit / "compare.json", summary)
        if comparison.pairs:
            pairs = {
                kind: {name: r.to_dict() for name, r in results.items()}
                for kind, results in comparison.pairs.items()
            }
            write_json(unit / "pairs.json", pairs)
        write_marker(
            unit,
            "partial" if reason else "complete",
            done if rows else len(indices),
            len(indices),
            reason,
            methods_done=[o.method for o in rows if not o.run.interrupted],
            pair_kinds_done=list(comparison.pairs),
            **({"methods_skipped": skipped} if skipped else {}),
        )
    point_latest_at(folder.parent, folder)


def works_on_pairs(spec: str) -> bool:
    """kiss-icp (as a method or a polish) and kiss-slam need a sequence's local map: not an isolated pair."""
    name, plus, polish = spec.strip().lower().partition("+")
    return name not in SEQUENTIAL_METHODS and (not plus or polish in ("none", *PAIR_POLISHES))


def pair_spec(spec: str) -> str:
    """The pairs protocol's spelling: a polish only where written out (``vcr`` is VCR-Net alone)."""
    name, _, polish = spec.strip().lower().partition("+")
    return name if polish in ("", "none") else f"{name}+{polish}"


def compare_pairs(
    settings: CompareSettings,
    comparison: Comparison,
    progress: ProgressFactory | None,
    kinds: tuple[str, ...] | None = None,
) -> None:
    """One table per pair kind into ``comparison.pairs`` (``kinds``: from :func:`pair_kinds_to_run`)."""
    specs = list(dict.fromkeys(pair_spec(s) for s in settings.methods if works_on_pairs(s)))
    left_out = [s for s in settings.methods if not works_on_pairs(s)]
    if left_out:
        comparison.notes.append(
            f"left out of the pairs protocol: {', '.join(left_out)} (kiss-icp, as a method or a polish, "
            "and kiss-slam need a sequence's local map)."
        )
    sequence = comparison.sequence
    if kinds is None:
        kinds = pair_kinds_to_run(settings, sequence)
    if sequence.gt_poses is None and "consecutive" in settings.pair_kinds:
        comparison.notes.append(f"no consecutive-pairs table: {sequence.name} has no ground-truth poses")
    if not kinds or not specs:
        return
    points = settings.pair_points or settings.vcr_points or default_pair_points(specs, settings.weights)
    comparison.pair_points = points
    options = {spec.partition("+")[0]: settings.method_options(spec) for spec in specs}
    indices = comparison.frame_indices
    with _progress(progress, f"building pairs ({points} points)", len(indices)) as advance:
        datasets = pair_sets(
            sequence,
            indices,
            points,
            settings.seed,
            kinds,
            progress=lambda *_: advance(),
            max_range=pair_input_range(specs, settings.weights),
        )
    for kind, pairs in datasets.items():
        with _progress(progress, f"registering {kind} pairs", len(pairs) * len(specs)) as advance:
            results = evaluate_pair_protocol(specs, pairs, options=options, progress=lambda *_: advance())
        comparison.pairs[kind] = results


def _progress(factory: ProgressFactory | None, title: str, total: int) -> AbstractContextManager[Any]:
    return factory(title, total) if factory is not None else nullcontext(lambda *_: None)


def _vcr_weights_config(specs: list[str], weights: Path | None) -> Any:
    if any(spec.partition("+")[0] == "vcr" for spec in specs):
        return read_weights(weights or default_weights_path("default"))[1]
    return None


def pair_input_range(specs: list[str], weights: Path | None) -> float:
    """The VCR weights' input range when a VCR row is compared (every method then sees the clouds the
    network was trained on), else ``run``'s crop."""
    config = _vcr_weights_config(specs, weights)
    return config.input_max_range if config is not None else PreprocessConfig().max_range


def default_pair_points(specs: list[str], weights: Path | None) -> int:
    """The VCR weights' N when a VCR row is compared (the N-point clouds the file runs on; it runs on
    fewer too, but was chosen and measured at N), else the paper's 1024."""
    config = _vcr_weights_config(specs, weights)
    return config.num_points if config is not None else 1024
