"""A small exception hierarchy, so the CLI can turn library failures into one clear line."""


class VcrOdomError(Exception):
    """Base of every error the library raises on purpose."""


class DataError(VcrOdomError, ValueError):
    """An input file or folder is missing or not in the expected format; the message names it."""


class ConfigError(VcrOdomError, ValueError):
    """An option or configuration value is out of range; the message names the option."""


class DataWarning(UserWarning):
    """Input data was usable but not as expected (NaN points dropped, no times.txt, an empty frame)."""


class MissingExtraError(ConfigError):
    """An optional dependency is not installed; the message names the pip extra that installs it.

    Its own class so that ``compare`` can show such a method as a "not installed" row and go on.
    """

    def __init__(self, package: str, extra: str, detail: str = "") -> None:
        self.package = package
        self.extra = extra
        super().__init__(f"{package} is {self.status}" + (f" ({detail})" if detail else ""))

    @property
    def status(self) -> str:
        """The short form, for a table cell: ``not installed: pip install 'vcr-odom[EXTRA]'``."""
        return f"not installed: pip install 'vcr-odom[{self.extra}]'"


class Interrupted(KeyboardInterrupt):
    """A signal asking a command to stop (SIGTERM from ``timeout``, systemd or a cluster scheduler;
    SIGHUP from a closed terminal; Ctrl-C), raised as Ctrl-C's KeyboardInterrupt is, so every ``except
    KeyboardInterrupt`` that keeps what was done keeps it for these too. ``label`` names it."""

    def __init__(self, signum: int, label: str) -> None:
        self.signum = signum
        self.label = label
        super().__init__(label)
