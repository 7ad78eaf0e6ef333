"""The terminal side of every command: the console, a progress bar for the frame loop, warnings as
one line each, and the exit codes (documented in ``vcr-odom --help`` and docs/usage.md)."""

from __future__ import annotations

import signal
import sys
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import NoReturn

import click
from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    ProgressColumn,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from vcr_odom.stop_signals import signal_label, stopping_signal

# Piped output (logs, CI, README tables) gets a wide console instead of rich's 80-column default.
console = Console() if sys.stdout.isatty() else Console(width=170)
notes = Console(stderr=True)
"""Warnings and side notes go to stderr, so ``--json -`` output stays parseable."""


def bar_columns(field: str) -> tuple[ProgressColumn, ...]:
    """A progress bar's columns: what, the bar, done of total, the task's ``field``, elapsed, ETA."""
    return (
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn(f"{{task.fields[{field}]}}"),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
    )


@contextmanager
def frame_progress(description: str, total: int) -> Iterator[Callable[..., None]]:
    """Yields a callback that advances the bar by one frame (its arguments are ignored)."""
    with Progress(*bar_columns("fps"), console=console, transient=False) as progress:
        task = progress.add_task(description, total=total, fps="")

        def advance(*_args: object) -> None:
            progress.advance(task)
            speed = progress.tasks[task].speed
            progress.update(task, fps=f"{speed:5.1f} fps" if speed else "")

        yield advance


def show_warnings_on_console() -> None:
    """Print library warnings (NaN points dropped, 10 Hz assumed, ...) as one short yellow line each."""

    def show(message: Warning | str, category: type[Warning], *_args: object, **_kwargs: object) -> None:
        notes.print(f"[yellow]warning:[/] {message}", highlight=False)

    warnings.showwarning = show


EXIT_DONE = 0
EXIT_ERROR = 1
"""The library's own error (:class:`~vcr_odom.errors.VcrOdomError`): one line naming the input."""
EXIT_USAGE = 2
"""A bad option or combination of options: click's own checks and the library's ``ConfigError``."""
EXIT_INTERRUPTED = 128 + signal.SIGINT
"""Ctrl-C (128 + SIGINT = 130, as shells report it): what was done is kept, marked ``partial``."""
EXIT_TERMINATED = 128 + signal.SIGTERM
"""SIGTERM (143: ``timeout``, ``kill``, systemd, cluster schedulers), handled as Ctrl-C is."""
EXIT_HANGUP = 128 + signal.SIGHUP
"""SIGHUP (129: the terminal closed), handled as Ctrl-C is."""

EXIT_CODES_HELP = (
    "\b\nExit codes:\n"
    f"  {EXIT_DONE:<4} done\n"
    f"  {EXIT_ERROR:<4} error: an input or output the command could not use (one line, no traceback)\n"
    f"  {EXIT_USAGE:<4} usage: a bad option, or options that do not go together\n"
    f"  {EXIT_INTERRUPTED:<4} interrupted (Ctrl-C): the partial result is kept, marked partial in its result.json\n"
    f"  {EXIT_TERMINATED:<4} stopped by SIGTERM (timeout, kill, systemd, a scheduler): as Ctrl-C\n"
    f"  {EXIT_HANGUP:<4} stopped by SIGHUP (the terminal closed): as Ctrl-C"
)


def interrupt_label() -> str:
    """What stopped the command, for its messages: ``Ctrl-C``, ``SIGTERM`` or ``SIGHUP``."""
    return signal_label(stopping_signal() or signal.SIGINT)


def exit_interrupted(message: str) -> NoReturn:
    """Say what was kept and leave with 128 + the signal that stopped the command (130 for Ctrl-C,
    143 for SIGTERM, 129 for SIGHUP): a script must not take a run cut short for a finished one."""
    notes.print(f"[yellow]{message}", highlight=False)
    raise click.exceptions.Exit(128 + (stopping_signal() or signal.SIGINT))
