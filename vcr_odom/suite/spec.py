"""The suite file (TOML): which methods, strides and datasets, checked before any cell runs.

Why TOML: the standard library reads it (``tomllib``), and a suite is a list of tables, which TOML
spells without indentation mistakes. Every mistake names the file and the key."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path
from typing import Any

from pydantic import Field, field_validator, model_validator

from vcr_odom.data.selection import FrameSelection
from vcr_odom.errors import ConfigError
from vcr_odom.evaluation.rows import canonical_row, parse_row_spec
from vcr_odom.odometry.chain import CONSULT_CHOICES
from vcr_odom.settings import Settings

DATASET_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")
"""A dataset's name becomes a folder: letters, digits, ``.``, ``_``, ``-``."""

SOURCE_KEYS = ("data_root", "folder", "dataloader")
PATH_KEYS = ("data_root", "folder", "poses", "calib", "times", "data")


class DatasetEntry(FrameSelection):
    """One ``[[dataset]]`` table: a name and ``run``'s data options (``data_root`` + ``seq``, or
    ``folder`` (+ ``poses``, ``times``, ``calib``), or ``dataloader`` + ``data`` (+ ``topic``)),
    optionally ``frames = "A:B"``; the strides are the suite's."""

    name: str

    @field_validator("name")
    @classmethod
    def _folder_name(cls, name: str) -> str:
        if not DATASET_NAME.match(name):
            raise ValueError("letters, digits, '.', '_' and '-' only (it names the dataset's folder)")
        return name

    @model_validator(mode="after")
    def _one_source(self) -> DatasetEntry:
        if "stride" in self.model_fields_set:
            raise ValueError(
                "stride: the suite's strides apply to every dataset (strides = [...] at the top)"
            )
        given = [key for key in SOURCE_KEYS if getattr(self, key) is not None]
        if len(given) != 1:
            raise ValueError(
                f"give exactly one of {', '.join(SOURCE_KEYS)}; got {', '.join(given) or 'none'}"
            )
        return self

    def selection(self, stride: int) -> FrameSelection:
        """``run``'s frame selection for this dataset at ``stride``."""
        return FrameSelection(**self.model_dump(exclude={"name", "stride"}), stride=stride)

    def resolved(self, base: Path) -> DatasetEntry:
        """``~`` expanded and relative paths taken from ``base`` (the suite file's folder), so a suite
        runs the same from anywhere."""
        paths = {key: getattr(self, key).expanduser() for key in PATH_KEYS if getattr(self, key) is not None}
        resolved = {key: base / path for key, path in paths.items()}
        return DatasetEntry(**{**self.model_dump(exclude={"stride"}), **resolved})


class SuiteSpec(Settings):
    """A whole suite: every dataset x method x stride is one cell.

    ``methods`` are spelled as ``run``/``compare`` spell them (``kiss-icp``, ``vcr``, ``vcr+icp``),
    ``+loops`` for ``vcr-odom map`` cells; ``consult`` and ``device`` apply to the methods that take them."""

    methods: list[str] = Field(min_length=1)
    strides: list[int] = Field(default=[1], min_length=1)
    dataset: list[DatasetEntry] = Field(min_length=1)
    """The ``[[dataset]]`` tables, in the file's order."""
    consult: str | None = None
    device: str = "cpu"

    @field_validator("methods")
    @classmethod
    def _known_methods(cls, methods: list[str]) -> list[str]:
        spelled = []
        for spec in methods:
            try:
                parse_row_spec(spec)
            except ConfigError as error:
                raise ValueError(str(error)) from None
            spelled.append(canonical_row(spec))
        if len(set(spelled)) != len(spelled):
            raise ValueError(f"a method is listed twice: {', '.join(methods)}")
        return spelled

    @field_validator("strides")
    @classmethod
    def _positive_strides(cls, strides: list[int]) -> list[int]:
        if any(stride < 1 for stride in strides) or len(set(strides)) != len(strides):
            raise ValueError(f"positive integers, each once; got {strides}")
        return strides

    @field_validator("consult")
    @classmethod
    def _known_consult(cls, consult: str | None) -> str | None:
        if consult is not None and consult not in CONSULT_CHOICES:
            raise ValueError(f"one of {', '.join(CONSULT_CHOICES)}")
        return consult

    @model_validator(mode="after")
    def _unique_names(self) -> SuiteSpec:
        names = [dataset.name for dataset in self.dataset]
        twice = sorted({name for name in names if names.count(name) > 1})
        if twice:
            raise ValueError(f"dataset names must differ (each names a folder): {', '.join(twice)} twice")
        return self


def load_suite(path: str | Path) -> SuiteSpec:
    """The suite in ``path``; a ConfigError that names the file (and the key) for any mistake."""
    path = Path(path)
    try:
        data: dict[str, Any] = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such suite file") from None
    except (OSError, UnicodeDecodeError) as error:
        raise ConfigError(f"{path}: cannot read the suite file ({error})") from None
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{path}: not valid TOML ({error})") from None
    try:
        suite = SuiteSpec(**data)
    except ConfigError as error:
        raise ConfigError(f"{path}: {error}") from None
    base = path.resolve().parent
    return suite.with_changes(dataset=[d.resolved(base) for d in suite.dataset])
