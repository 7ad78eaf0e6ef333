"""Several methods on the same frames, side by side: what ``vcr-odom compare`` does, callable from Python.

The odometry protocol chains each method over the frames (one result sub-folder each); the pairs
protocol (:mod:`vcr_odom.evaluation.pairs`) registers isolated pairs. Nothing here prints: the caller
gets the outcomes and renders them.
"""

from __future__ import annotations

from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from pydantic import Field

from vcr_odom.data.base import LidarSequence
from vcr_odom.data.selection import FrameSelection
from vcr_odom.evaluation.pairs import PAIR_KINDS, PairProtocolResult, evaluate_pair_protocol, pair_sets
from vcr_odom.evaluation.pairs_polish import PAIR_POLISHES
from vcr_odom.metrics import EvaluationReport
from vcr_odom.model.weights import default_weights_path, read_weights
from vcr_odom.odometry.chain import Consult, Odometry
from vcr_odom.odometry.factory import DEFAULT_CONSULT, build_odometry, canonical_spec
from vcr_odom.odometry.limits import InitialGuess
from vcr_odom.odometry.loop import OdometryRun
from vcr_odom.odometry.outputs import ground_truth_for, run_summary
from vcr_odom.odometry.run import ProgressFactory, run_and_save, vcr_options
from vcr_odom.plots import plot_trajectories
from vcr_odom.preprocess import PreprocessConfig
from vcr_odom.results import create_result_folder, provenance, write_json
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
    consult: Consult = DEFAULT_CONSULT
    results_dir: Path = Path("results")

    def method_options(self, spec: str) -> dict[str, Any]:
        return vcr_options(spec.partition("+")[0].strip().lower(), self.weights, self.device, self.vcr_passes)


@dataclass
class MethodOutcome:
    """One row of the odometry comparison."""

    method: str
    needs_initial_guess: bool
    run: OdometryRun
    report: EvaluationReport | None


@dataclass
class Comparison:
    """What a comparison produced: the rows of each protocol and notes on what was left out."""

    folder: Path
    sequence: LidarSequence
    frame_indices: list[int]
    odometry: list[MethodOutcome] = field(default_factory=list)
    pairs: dict[str, dict[str, PairProtocolResult]] = field(default_factory=dict)
    pair_points: int = 0
    notes: list[str] = field(default_factory=list)


def run_comparison(settings: CompareSettings, progress: ProgressFactory | None = None) -> Comparison:
    """One result folder; the odometry rows, the pairs tables, or both."""
    for spec in settings.methods:
        canonical_spec(spec)  # a bad name fails before any work
    sequence = settings.selection.open()
    indices = settings.selection.indices(sequence)
    folder = create_result_folder(
        settings.results_dir, f"compare_{sequence.name}_stride{settings.selection.stride}"
    )
    write_json(
        folder / "config.json",
        provenance({"command": "compare", "sequence": sequence.name, **settings.to_dict()}),
    )
    comparison = Comparison(folder, sequence, indices)
    if settings.protocol in ("odometry", "both"):
        comparison.odometry = compare_methods(settings, sequence, indices, folder, progress)
    if settings.protocol in ("pairs", "both"):
        compare_pairs(settings, comparison, progress)
    return comparison


def compare_methods(
    settings: CompareSettings,
    sequence: LidarSequence,
    frame_indices: list[int],
    folder: Path,
    progress: ProgressFactory | None = None,
) -> list[MethodOutcome]:
    """Each method over the same frames (one sub-folder each), trajectories overlaid in one plot.

    Ctrl-C stops the method in progress and skips the rest; what finished is kept and plotted.
    """
    outcomes: list[MethodOutcome] = []
    for spec in dict.fromkeys(canonical_spec(s) for s in settings.methods):
        odometry = build_odometry(spec, initial_guess=settings.initial_guess, **settings.method_options(spec))
        needs_guess = odometry.registrar.needs_initial_guess if isinstance(odometry, Odometry) else True
        with _progress(progress, spec, len(frame_indices)) as advance:
            run, report = run_and_save(sequence, odometry, frame_indices, folder / spec, progress=advance)
        outcomes.append(MethodOutcome(spec, needs_guess, run, report))
        if run.interrupted:
            break
    if outcomes:
        stride = frame_indices[1] - frame_indices[0] if len(frame_indices) > 1 else 1
        plot_trajectories(
            folder / "trajectories.png",
            {o.method: o.run.poses for o in outcomes if len(o.run.poses)},
            ground_truth_for(sequence, frame_indices),
            title=f"{sequence.name}, stride {stride}",
        )
        rows = {
            o.method: {"run": run_summary(o.run), **(o.report.to_dict() if o.report else {})}
            for o in outcomes
        }
        write_json(folder / "compare.json", rows)
    return outcomes


def works_on_pairs(spec: str) -> bool:
    """kiss-icp, as a method or a polish, needs a sequence's local map: not an isolated pair."""
    name, plus, polish = spec.strip().lower().partition("+")
    return name != "kiss-icp" and (not plus or polish in ("none", *PAIR_POLISHES))


def pair_spec(spec: str) -> str:
    """The pairs protocol's spelling: a polish only where written out (``vcr`` is VCR-Net alone)."""
    name, _, polish = spec.strip().lower().partition("+")
    return name if polish in ("", "none") else f"{name}+{polish}"


def compare_pairs(
    settings: CompareSettings, comparison: Comparison, progress: ProgressFactory | None
) -> None:
    """One table per pair kind into ``comparison.pairs``; ``pairs.json`` maps kind -> method -> figures."""
    specs = list(dict.fromkeys(pair_spec(s) for s in settings.methods if works_on_pairs(s)))
    left_out = [s for s in settings.methods if not works_on_pairs(s)]
    if left_out:
        comparison.notes.append(
            f"left out of the pairs protocol: {', '.join(left_out)} (kiss-icp, as a method or a polish, "
            "needs a sequence's local map)."
        )
    kinds = tuple(settings.pair_kinds)
    sequence = comparison.sequence
    if "consecutive" in kinds and sequence.gt_poses is None:
        comparison.notes.append(f"no consecutive-pairs table: {sequence.name} has no ground-truth poses")
        kinds = tuple(k for k in kinds if k != "consecutive")
    if not kinds or not specs:
        return
    points = settings.pair_points or default_pair_points(specs, settings.weights)
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
    write_json(
        comparison.folder / "pairs.json",
        {
            kind: {name: r.to_dict() for name, r in results.items()}
            for kind, results in comparison.pairs.items()
        },
    )


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
    """The VCR weights' N when a VCR row is compared (the network is trained on N-point clouds), else
    the paper's 1024."""
    config = _vcr_weights_config(specs, weights)
    return config.num_points if config is not None else 1024
