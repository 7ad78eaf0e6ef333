"""A rich progress bar for the frame loop."""

from __future__ import annotations

import sys
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

# Piped output (logs, CI, README tables) gets a wide console instead of rich's 80-column default.
console = Console() if sys.stdout.isatty() else Console(width=170)
notes = Console(stderr=True)
"""Warnings and side notes go to stderr, so ``--json -`` output stays parseable."""


@contextmanager
def frame_progress(description: str, total: int) -> Iterator[Callable[..., None]]:
    """Yields a callback that advances the bar by one frame (its arguments are ignored)."""
    columns = (
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[fps]}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=console, transient=False) as progress:
        task = progress.add_task(description, total=total, fps="")

        def advance(*_args: object) -> None:
            progress.advance(task)
            speed = progress.tasks[task].speed
            progress.update(task, fps=f"{speed:5.1f} fps" if speed else "")

        yield advance


def show_warnings_on_console() -> None:
    """Print library warnings (NaN points dropped, 10 Hz assumed, ...) as one short yellow line each."""

    def show(message, category, *_args, **_kwargs) -> None:
        notes.print(f"[yellow]warning:[/] {message}", highlight=False)

    warnings.showwarning = show
