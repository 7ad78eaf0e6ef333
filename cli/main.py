"""The ``vcr-odom`` command: a thin click group; every command lives in its own module.

:func:`main`, the console script, first makes SIGTERM (``timeout``, systemd, cluster schedulers) and
SIGHUP (a closed terminal) stop a command as Ctrl-C does, then imports the commands (torch, open3d:
seconds), so an interrupt at any moment leaves with its exit code and no traceback. That is why this
module imports nothing heavy at its top: ``cli``, the click group, is built on first use
(``from vcr_odom.cli.main import cli`` still works).
"""

from __future__ import annotations

import io
import signal
import sys
from functools import cache
from typing import TYPE_CHECKING, Any

from vcr_odom.stop_signals import (  # also importable from here, as before
    STOP_SIGNALS,
    signal_label,
    stop_on_signals,
    stopping_signal,
)

if TYPE_CHECKING:
    import click


def main() -> None:
    """The console script: signals first, then the commands, then the command line."""
    stop_on_signals()
    try:
        try:
            group = _group()
        except KeyboardInterrupt:
            signum = stopping_signal() or signal.SIGINT
            sys.stderr.write(f"Interrupted ({signal_label(signum)}) while starting; nothing was written.\n")
            sys.exit(128 + signum)
        group(prog_name="vcr-odom")
    finally:  # done (or stopped and written): a signal from here on would only interrupt Python's exit
        for signum in STOP_SIGNALS:  # (a traceback from an exit handler, or a death by the signal)
            signal.signal(signum, signal.SIG_IGN)


@cache
def _group() -> click.Group:
    """The click group with every command (imports them all: seconds, for torch and open3d)."""
    import click

    from vcr_odom.cli.benchmark import benchmark
    from vcr_odom.cli.compare import compare
    from vcr_odom.cli.demo import demo
    from vcr_odom.cli.evaluate import evaluate
    from vcr_odom.cli.map import map_command
    from vcr_odom.cli.options import FriendlyGroup
    from vcr_odom.cli.progress import EXIT_CODES_HELP, show_warnings_on_console
    from vcr_odom.cli.run import run
    from vcr_odom.cli.synth import synth
    from vcr_odom.cli.train import cache as cache_command
    from vcr_odom.cli.train import pretrain_command, train_command
    from vcr_odom.cli.view import view

    @click.group(
        cls=FriendlyGroup, context_settings={"help_option_names": ["-h", "--help"]}, epilog=EXIT_CODES_HELP
    )
    @click.version_option(package_name="vcr-odom")
    def cli() -> None:
        """LiDAR odometry with VCR-Net and classical baselines, scored honestly against ground truth."""
        show_warnings_on_console()
        if isinstance(sys.stdout, io.TextIOWrapper):  # a path that is not UTF-8 prints as "\udcff",
            sys.stdout.reconfigure(errors="backslashreplace")  # not a crash after the work is done

    commands = (
        run,
        map_command,
        evaluate,
        view,
        compare,
        benchmark,
        synth,
        demo,
        cache_command,
        pretrain_command,
        train_command,
    )
    for command in commands:
        cli.add_command(command)
    return cli


def __getattr__(name: str) -> Any:
    """``cli``, built on first use (see the module's docstring)."""
    if name == "cli":
        return _group()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


if __name__ == "__main__":
    main()
