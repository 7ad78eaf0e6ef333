"""The one epoch loop behind :func:`train` and :func:`pretrain`: set up (or resume), train, validate, record.

:func:`train` optimises the paper's correspondence loss (§IV-F; the transformation loss and the pose
RMSEs are only monitored) and :func:`pretrain` the encoder's triplet loss (Algorithm 1); a
:class:`~vcr_odom.training.tasks.Task` is what differs between them.

Why resume is exact: the checkpoint holds model, optimiser, scheduler, grad scaler, best score, history
and every rank's RNG states, and each epoch's data order depends only on (seed, epoch) (a generator
seeded per epoch, ``DistributedSampler.set_epoch``, the dataset's own ``set_epoch``), so an interrupted
run continued with ``resume=True`` computes the same parameters as one that never stopped. With
``checkpoint_every`` the checkpoint is also written inside an epoch, with the steps done and the
epoch's running sums; a resumed run skips those steps' batches (the same ones: the order is fixed).
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import torch
import torch.distributed as dist
from torch import Tensor, nn
from torch.nn.parallel import DistributedDataParallel
from torch.utils.data import (
    DataLoader,
    Dataset,
    DistributedSampler,
    RandomSampler,
    Sampler,
    SequentialSampler,
)

from vcr_odom.errors import DataError
from vcr_odom.model.config import VcrConfig
from vcr_odom.model.network import VCRNet
from vcr_odom.model.weights import load_weights, save_weights
from vcr_odom.results import provenance, write_json
from vcr_odom.training.checkpoint import check_resumable, load_checkpoint, save_checkpoint
from vcr_odom.training.config import Progress, ProgressEvent, TrainConfig, TrainResult
from vcr_odom.training.runtime import (
    DistContext,
    all_reduce_sum,
    gather_rng_states,
    init_distributed,
    parameter_groups,
    resolve_device,
    seed_everything,
    set_rng_state,
)
from vcr_odom.training.tasks import Pretraining, Registration, Task, unwrap


def train(
    model_config: VcrConfig,
    train_dataset: Dataset,
    val_dataset: Dataset,
    train_config: TrainConfig,
    resume: bool = False,
    progress: Progress | None = None,
) -> TrainResult:
    """Train VCR-Net with the correspondence loss; ``best.safetensors`` is chosen on ``val_dataset``."""
    return fit(Registration(), model_config, train_dataset, val_dataset, train_config, resume, progress)


def pretrain(
    model_config: VcrConfig,
    train_dataset: Dataset,
    val_dataset: Dataset,
    train_config: TrainConfig,
    resume: bool = False,
    progress: Progress | None = None,
) -> TrainResult:
    """Pre-train the encoder with the triplet loss. Its ``best.safetensors`` holds a whole VCRNet (encoder
    trained, the rest at initialisation), to pass as ``TrainConfig.init_weights`` to :func:`train`."""
    return fit(Pretraining(), model_config, train_dataset, val_dataset, train_config, resume, progress)


@dataclass
class Session:
    """Everything one process of a run holds; ``module`` is what forward/backward go through (the
    task's trainable module, DDP-wrapped under torchrun), ``net`` the whole VCRNet that is saved."""

    task: Task
    model_config: VcrConfig
    config: TrainConfig
    ctx: DistContext
    device: torch.device
    net: VCRNet
    module: nn.Module
    optimiser: torch.optim.Optimizer
    scheduler: torch.optim.lr_scheduler.LRScheduler
    scaler: torch.amp.GradScaler
    amp: bool
    amp_dtype: torch.dtype
    start_epoch: int = 0
    start_step: int = 0
    partial: dict[str, Any] = field(default_factory=dict)
    best_score: float = math.inf
    best_epoch: int = -1
    history: list[dict[str, Any]] = field(default_factory=list)

    def autocast(self) -> torch.autocast:
        """Mixed precision on CUDA only (``amp`` is False elsewhere)."""
        return torch.autocast(self.device.type, dtype=self.amp_dtype, enabled=self.amp)


def fit(
    task: Task,
    model_config: VcrConfig,
    train_dataset: Dataset,
    val_dataset: Dataset,
    config: TrainConfig,
    resume: bool = False,
    progress: Progress | None = None,
) -> TrainResult:
    """Run ``task`` for ``config.epochs`` epochs (from the checkpoint's next epoch with ``resume``)."""
    if len(train_dataset) == 0 or len(val_dataset) == 0:
        raise DataError("training and validation sets must both hold at least one pair")
    ctx = init_distributed(config.device)
    try:
        session = _start(task, model_config, config, resume, ctx)
        if progress is not None and ctx.main:
            sizes = {"train_pairs": len(train_dataset), "val_pairs": len(val_dataset)}
            progress(ProgressEvent("start", task.name, session.start_epoch, config.epochs, metrics=sizes))
        started = time.perf_counter()
        for epoch in range(session.start_epoch, config.epochs):
            done = epoch - session.start_epoch
            if done and config.time_limit_s is not None:
                elapsed = time.perf_counter() - started
                if elapsed * (done + 1) / done > config.time_limit_s:
                    break
            train_metrics = _train_epoch(session, train_dataset, epoch, progress)
            session.scheduler.step()
            val_metrics = _validate(session, val_dataset, epoch)
            _end_epoch(session, epoch, train_metrics, val_metrics, progress)
    finally:
        if ctx.owns_group:
            dist.destroy_process_group()
    out = config.out
    return TrainResult(
        session.net.eval(),
        out,
        out / "best.safetensors",
        out / "last.pt",
        session.history,
        session.best_epoch,
        session.best_score,
    )


def _start(
    task: Task, model_config: VcrConfig, config: TrainConfig, resume: bool, ctx: DistContext
) -> Session:
    """Seed, build model and optimiser, restore the checkpoint if resuming, wrap in DDP if launched so."""
    device = resolve_device(config.device, ctx.local_rank)
    if device.type == "cuda":
        torch.cuda.set_device(device)
    if config.deterministic:
        torch.use_deterministic_algorithms(True, warn_only=True)
        torch.backends.cudnn.benchmark = False
    seed_everything(config.seed + ctx.rank)
    if config.init_weights is not None and not resume:
        net, _, _ = load_weights(config.init_weights, model_config, inference_from_config=True)
    else:
        net = VCRNet(model_config)
    net.to(device).train()
    trainable = task.trainable(net)
    optimiser = torch.optim.Adam(parameter_groups(trainable, config.weight_decay), lr=config.lr)
    amp = config.amp and device.type == "cuda"
    amp_dtype = getattr(torch, config.amp_dtype)
    session = Session(
        task=task,
        model_config=model_config,
        config=config,
        ctx=ctx,
        device=device,
        net=net,
        module=trainable,
        optimiser=optimiser,
        scheduler=torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, T_max=config.epochs),
        scaler=torch.amp.GradScaler("cuda", enabled=amp and amp_dtype == torch.float16),
        amp=amp,
        amp_dtype=amp_dtype,
    )
    if resume:
        path = config.out / "last.pt"
        state = load_checkpoint(path, task.name, model_config)
        check_resumable(path, state, optimiser)
        session.model_config = session.net.config = state["model_config"]
        try:
            _restore(session, state)
        except (KeyError, IndexError, TypeError, ValueError, RuntimeError) as error:  # what the checks
            reason = (str(error).splitlines() or [type(error).__name__])[0]  # above did not foresee
            raise DataError(f"{path}: cannot resume from this checkpoint: {reason}") from error
    elif ctx.main:
        config.out.mkdir(parents=True, exist_ok=True)
        record = {"task": task.name, "model": model_config.to_dict(), "train": config.to_dict()}
        write_json(config.out / "run.json", provenance(record))
    if ctx.world > 1:
        ids = [device.index] if device.type == "cuda" else None
        session.module = DistributedDataParallel(trainable, device_ids=ids)
    return session


def _restore(session: Session, state: dict[str, Any]) -> None:
    session.net.load_state_dict(state["model"])
    session.optimiser.load_state_dict(state["optimiser"])
    session.scheduler.load_state_dict(state["scheduler"])
    session.scaler.load_state_dict(state["scaler"])
    session.start_epoch = state["epoch"] + 1
    within = state.get("within_epoch")  # absent in checkpoints written at an epoch's end
    if within is not None:
        session.start_epoch, session.start_step = within["epoch"], within["step"]
        session.partial = {"sums": dict(within["sums"]), "count": within["count"]}
    session.best_score, session.best_epoch = state["best_score"], state["best_epoch"]
    session.history = list(state["history"])
    rng = state["rng"]
    set_rng_state(rng[session.ctx.rank] if session.ctx.rank < len(rng) else rng[0])


def _end_epoch(
    session: Session,
    epoch: int,
    train_metrics: dict[str, float],
    val_metrics: dict[str, float],
    progress: Progress | None,
) -> None:
    """Score, history entry and (rank 0) best.safetensors, last.pt, history.json; then a barrier."""
    config, task = session.config, session.task
    score = _score(val_metrics, config)
    improved = score < session.best_score
    if improved:
        session.best_score, session.best_epoch = score, epoch
    entry: dict[str, Any] = {"epoch": epoch, "lr": session.optimiser.param_groups[0]["lr"]}
    entry.update({"score": score, "best": improved})
    entry.update({f"train_{k}": v for k, v in train_metrics.items()})
    entry.update({f"val_{k}": v for k, v in val_metrics.items()})
    session.history.append(entry)
    rng = gather_rng_states(session.ctx)  # collective: every rank takes part
    if session.ctx.main:
        out = config.out
        out.mkdir(parents=True, exist_ok=True)
        if improved:
            metadata = {"task": task.name, **entry, "train_config": config.to_dict()}
            save_weights(out / "best.safetensors", session.net, session.model_config, metadata)
        save_checkpoint(out / "last.pt", _state(session, epoch, rng))
        write_json(out / "history.json", session.history)
        if progress is not None:
            progress(ProgressEvent("epoch", task.name, epoch, config.epochs, metrics=entry))
    if session.ctx.world > 1:
        dist.barrier()


def _state(
    session: Session, completed_epoch: int, rng: list[dict[str, Any]], within: dict[str, Any] | None = None
) -> dict[str, Any]:
    """What ``last.pt`` holds; ``within`` marks a checkpoint written inside the epoch after
    ``completed_epoch`` (its steps done and running sums)."""
    state = {
        "task": session.task.name,
        "epoch": completed_epoch,
        "model": session.net.state_dict(),
        "optimiser": session.optimiser.state_dict(),
        "scheduler": session.scheduler.state_dict(),
        "scaler": session.scaler.state_dict(),
        "rng": rng,
        "best_score": session.best_score,
        "best_epoch": session.best_epoch,
        "history": session.history,
        "model_config": session.model_config.to_dict(),
        "train_config": session.config.to_dict(),
    }
    if within is not None:
        state["within_epoch"] = within
    return state


def _checkpoint_within_epoch(
    session: Session, epoch: int, step: int, sums: dict[str, float], count: int
) -> None:
    rng = gather_rng_states(session.ctx)  # collective: every rank takes part
    if session.ctx.main:
        within = {"epoch": epoch, "step": step, "sums": dict(sums), "count": count}
        session.config.out.mkdir(parents=True, exist_ok=True)
        save_checkpoint(session.config.out / "last.pt", _state(session, epoch - 1, rng, within))
    if session.ctx.world > 1:
        dist.barrier()


def _train_epoch(
    session: Session, dataset: Dataset, epoch: int, progress: Progress | None
) -> dict[str, float]:
    config = session.config
    _set_epoch(dataset, epoch)
    session.module.train()
    skip = session.start_step if epoch == session.start_epoch else 0
    loader = _loader(dataset, config, epoch, shuffle=True, ctx=session.ctx, skip_batches=skip)
    steps = skip + len(loader)
    sums: dict[str, float] = dict(session.partial.get("sums", {})) if skip else {}
    count = session.partial.get("count", 0) if skip else 0
    for step, batch in enumerate(loader, start=skip + 1):
        batch = _to_device(batch, session.device)
        with session.autocast():
            loss, metrics = session.task.loss(session.module, batch, config)
        if not torch.isfinite(loss):
            raise FloatingPointError(f"{session.task.name}: non-finite loss at epoch {epoch}, step {step}")
        session.optimiser.zero_grad(set_to_none=True)
        session.scaler.scale(loss).backward()
        if config.grad_clip is not None:
            session.scaler.unscale_(session.optimiser)
            torch.nn.utils.clip_grad_norm_(session.module.parameters(), config.grad_clip)
        session.scaler.step(session.optimiser)
        session.scaler.update()
        count += _accumulate(sums, metrics, batch["source"].shape[0])
        every = config.checkpoint_every
        if every is not None and step % every == 0 and step < steps:
            _checkpoint_within_epoch(session, epoch, step, sums, count)
        if progress is not None and session.ctx.main and (step % config.log_every == 0 or step == steps):
            running = {k: v / count for k, v in sums.items()}
            progress(ProgressEvent("step", session.task.name, epoch, config.epochs, step, steps, running))
    return _finish(sums, count, session)


@torch.no_grad()
def _validate(session: Session, dataset: Dataset, epoch: int) -> dict[str, float]:
    """Validation means over the whole set (sharded across ranks, then summed)."""
    _set_epoch(dataset, epoch)
    session.module.eval()
    inner = unwrap(session.module)  # no DDP hooks needed without backward
    sums: dict[str, float] = {}
    count = 0
    for batch in _loader(dataset, session.config, epoch, shuffle=False, ctx=session.ctx):
        batch = _to_device(batch, session.device)
        with session.autocast():
            _, metrics = session.task.loss(inner, batch, session.config)
        count += _accumulate(sums, metrics, batch["source"].shape[0])
    return _finish(sums, count, session)


def _accumulate(sums: dict[str, float], metrics: dict[str, Tensor], size: int) -> int:
    for name, value in metrics.items():
        sums[name] = sums.get(name, 0.0) + float(value) * size
    return size


def _loader(
    dataset: Dataset,
    config: TrainConfig,
    epoch: int,
    shuffle: bool,
    ctx: DistContext,
    skip_batches: int = 0,
) -> DataLoader:
    """A loader whose order depends only on (seed, epoch), so a resumed epoch reads the same batches;
    ``skip_batches`` leaves out the first ones (done before a mid-epoch checkpoint)."""
    generator = torch.Generator().manual_seed(config.seed * 1_000_003 + epoch)
    if ctx.world > 1:
        sampler: Any = DistributedSampler(dataset, ctx.world, ctx.rank, shuffle=shuffle, seed=config.seed)
        sampler.set_epoch(epoch)
    elif shuffle:
        sampler = RandomSampler(dataset, generator=generator)
    else:
        sampler = SequentialSampler(dataset)
    if skip_batches:
        sampler = _SkipFirst(sampler, skip_batches * config.batch_size)
    return DataLoader(
        dataset,
        batch_size=config.batch_size,
        sampler=sampler,
        num_workers=config.num_workers,
        generator=generator,
        drop_last=False,
        persistent_workers=False,
    )


class _SkipFirst(Sampler):
    """``sampler``'s indices without the first ``count``. Lazy on purpose: the loader draws its base
    seed from the shared generator before the sampler draws its permutation, as without skipping."""

    def __init__(self, sampler: Sampler, count: int) -> None:
        self.sampler, self.count = sampler, count

    def __iter__(self) -> Iterator[int]:
        return itertools.islice(iter(self.sampler), self.count, None)

    def __len__(self) -> int:
        return max(len(self.sampler) - self.count, 0)


def _to_device(batch: dict[str, Any], device: torch.device) -> dict[str, Any]:
    return {k: v.to(device, non_blocking=True) if isinstance(v, Tensor) else v for k, v in batch.items()}


def _set_epoch(dataset: Dataset, epoch: int) -> None:
    set_epoch = getattr(dataset, "set_epoch", None)
    if callable(set_epoch):
        set_epoch(epoch)


def _finish(sums: dict[str, float], count: int, session: Session) -> dict[str, float]:
    """Means over all ranks; squared pose errors become RMSEs (``rot_rmse_deg``, ``trans_rmse_m``)."""
    names = sorted(sums)
    totals = all_reduce_sum([sums[n] for n in names] + [float(count)], session.device, session.ctx)
    means = {n: totals[i] / max(totals[-1], 1.0) for i, n in enumerate(names)}
    if "rot_sq_deg" in means:
        means["rot_rmse_deg"] = math.sqrt(means.pop("rot_sq_deg"))
        means["trans_rmse_m"] = math.sqrt(means.pop("trans_sq_m"))
    return means


def _score(metrics: dict[str, float], config: TrainConfig) -> float:
    """Lower is better. ``rmse`` normalises each RMSE by the issue's target (1°, 0.25 m); ``inliers``
    is one minus the inlier ratio."""
    if config.select_on == "rmse" and "rot_rmse_deg" in metrics:
        return metrics["rot_rmse_deg"] / 1.0 + metrics["trans_rmse_m"] / 0.25
    if config.select_on == "inliers" and "inlier_ratio" in metrics:
        return 1.0 - metrics["inlier_ratio"]
    return metrics["loss"]
