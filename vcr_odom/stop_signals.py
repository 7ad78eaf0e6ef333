"""The signals that stop a command as Ctrl-C does (SIGINT, SIGTERM, SIGHUP), in the library: the
commands install them first thing (``vcr_odom.cli.main``), and so does every process a benchmark
suite starts for its cells (:mod:`vcr_odom.suite.executors`), so a stopped cell keeps its partial
result wherever it runs."""

from __future__ import annotations

import os
import signal
from types import FrameType

from vcr_odom.errors import Interrupted

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""The signals that ask a command to stop, as Ctrl-C does (see :class:`~vcr_odom.errors.Interrupted`)."""
_stopping: list[int] = []
"""The signal that is stopping the command, once one came (a list: set from a signal handler)."""


def signal_label(signum: int) -> str:
    """``Ctrl-C`` for SIGINT, else the signal's name (``SIGTERM``)."""
    return "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name


def stopping_signal() -> int | None:
    """The signal that stopped this command (None: none came, as in tests calling ``cli`` directly)."""
    return _stopping[0] if _stopping else None


def stop_on_signals() -> None:
    """Ctrl-C, SIGTERM and SIGHUP raise :class:`~vcr_odom.errors.Interrupted` (a KeyboardInterrupt,
    so what was done is kept as for Ctrl-C); those that come after it are held: the command is already
    stopping, and a second interrupt must not cut short the writing of what was done. A signal ignored
    already stays ignored: ``nohup`` ignores SIGHUP, a shell ignores Ctrl-C for a job started with ``&``."""
    for signum in STOP_SIGNALS:
        if signal.getsignal(signum) is not signal.SIG_IGN:
            signal.signal(signum, _stop)


def _stop(signum: int, _frame: FrameType | None) -> None:
    if _stopping:
        os.write(2, b"vcr-odom: already stopping; writing what was done first (Ctrl-\\ abandons it)\n")
        return
    _stopping.append(signum)
    raise Interrupted(signum, signal_label(signum))
