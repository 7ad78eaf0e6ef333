"""A small exception hierarchy, so the CLI can turn library failures into one clear line."""


class VcrOdomError(Exception):
    """Base of every error the library raises on purpose."""


class DataError(VcrOdomError, ValueError):
    """An input file or folder is missing or not in the expected format; the message names it."""


class ConfigError(VcrOdomError, ValueError):
    """An option or configuration value is out of range; the message names the option."""


class DataWarning(UserWarning):
    """Input data was usable but not as expected (NaN points dropped, no times.txt, an empty frame)."""
