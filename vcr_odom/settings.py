"""One base for every configuration: validated on construction, frozen, and a JSON round-trip.

Why pydantic (already installed with kiss-icp, whose own config uses it): each configuration used to
validate by hand in ``__post_init__`` with its own ``to_dict``/``from_dict``; now a field's type and
bounds are declared once, and every configuration dumps, loads and copies the same way. A bad value
raises :class:`~vcr_odom.errors.ConfigError` (one line per bad field, naming it), so the CLI prints it
as a usage error instead of a traceback.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any, ClassVar, Self

from pydantic import BaseModel, ConfigDict, ValidationError

from vcr_odom.errors import ConfigError


def describe_validation_error(owner: str, error: ValidationError) -> str:
    """``owner: field: message (got value); ...`` for the problems pydantic found, on one line."""
    lines = []
    for problem in error.errors(include_url=False):
        where = ".".join(str(part) for part in problem["loc"])
        message = problem["msg"].removeprefix("Value error, ")
        got = problem.get("input")
        if not where:  # a rule across fields: its message names them
            lines.append(message)
            continue
        shown = "" if problem["type"] == "missing" else f" (got {got!r})"
        lines.append(f"{where}: {message}{shown}")
    return f"{owner}: " + "; ".join(lines)


class Settings(BaseModel):
    """Frozen, strict about unknown fields, and converted to :class:`ConfigError` on bad values."""

    model_config = ConfigDict(frozen=True, extra="forbid", validate_default=True)
    toml_title: ClassVar[str] = "settings"
    """The first line of :meth:`dump_toml`'s file."""
    toml_listed_by: ClassVar[str] = "--dump-config"
    """The command that writes such a file, named where a file holds an unknown field."""

    def __init__(self, **data: Any) -> None:
        try:
            super().__init__(**data)
        except ValidationError as error:
            raise ConfigError(describe_validation_error(type(self).__name__, error)) from None

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able dict (what result folders and weight files store)."""
        return self.model_dump(mode="json")

    @classmethod
    def from_dict(cls, data: Any) -> Self:
        """Inverse of :meth:`to_dict`; a non-dict or an unknown key raises :class:`ConfigError`."""
        if not isinstance(data, dict):
            raise ConfigError(f"{cls.__name__}: a dict is needed; got {type(data).__name__}")
        return cls(**data)

    def with_changes(self, **changes: Any) -> Self:
        """A copy with some fields changed, validated again (``model_copy`` would skip validation)."""
        return type(self)(**{**self.model_dump(), **changes})

    def dump_toml(self) -> str:
        """The settings as a TOML file a user edits (each field with its description as a comment), as
        kiss-icp's users keep theirs."""
        lines = [f"# {self.toml_title}"]
        for name, field in type(self).model_fields.items():
            value = getattr(self, name)
            text = str(value).lower() if isinstance(value, bool) else repr(value)
            lines += [f"# {field.description}"] if field.description else []
            lines += [f"# {name} is unset (TOML has no null)" if value is None else f"{name} = {text}"]
        return "\n".join(lines) + "\n"

    @classmethod
    def from_toml(cls, path: Path) -> dict[str, Any]:
        """The fields a TOML file sets (a missing file, bad TOML or an unknown field names ``path``)."""
        try:
            data = tomllib.loads(Path(path).read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise ConfigError(f"--config {path}: no such file") from None
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as error:
            raise ConfigError(f"--config {path}: not a readable TOML file ({error})") from None
        unknown = sorted(set(data) - set(cls.model_fields))
        if unknown:
            raise ConfigError(
                f"--config {path}: unknown setting(s) {', '.join(unknown)}; `{cls.toml_listed_by}` lists them"
            )
        try:
            cls(**data)
        except ConfigError as error:
            raise ConfigError(f"--config {path}: {error}") from None
        return data
