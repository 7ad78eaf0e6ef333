"""The suite file (TOML): which methods, strides and datasets, checked before any cell runs.

Why TOML: the standard library reads it (``tomllib``), and a suite is a list of tables, which TOML
spells without indentation mistakes. Every mistake names the file and the key.

Why checked so strictly, and all before the first cell: a typo found by the cell that reads it is
found hours into a suite, once per cell; and a value coerced quietly (``strides = [true]`` read as
stride 1, ``"3"`` as 3) runs something other than what the file says. So the file's own types are
checked as TOML wrote them (a bool is not an integer), an unknown key is named with the closest valid
one, and :func:`check_inputs` checks every path, loader and device before anything runs."""

from __future__ import annotations

import difflib
import re
import tomllib
import warnings
from pathlib import Path
from typing import Any

from pydantic import Field, field_validator, model_validator

from vcr_odom.data.selection import FrameSelection
from vcr_odom.errors import ConfigError, DataWarning
from vcr_odom.evaluation.rows import canonical_row, parse_row_spec
from vcr_odom.odometry.chain import CONSULT_CHOICES
from vcr_odom.settings import Settings

DATASET_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
"""A dataset's name becomes a folder: letters, digits, ``.``, ``_``, ``-`` (matched whole: ``fullmatch``,
so a final newline is not let through as ``$`` would)."""

DEVICES = ("auto", "cpu", "cuda")
"""``device``'s values (as :func:`vcr_odom.device.resolve_device` takes them; not imported from there,
which imports torch)."""

SOURCE_KEYS = ("data_root", "folder", "dataloader")
PATH_KEYS = ("data_root", "folder", "poses", "calib", "times", "data")
FOLDER_KEYS = ("data_root", "folder")
"""Path keys that must name a folder (``data`` may be a file or a folder, the others files)."""

SUITE_TYPES: dict[str, tuple[type, ...]] = {
    "methods": (list, str),
    "strides": (list, int),
    "dataset": (list, dict),
    "consult": (str,),
    "device": (str,),
}
"""Each top-level key's TOML type: ``(list, item type)`` for an array, else ``(type,)``."""

DATASET_TYPES: dict[str, type] = {
    "name": str,
    "data_root": str,
    "seq": str,
    "folder": str,
    "poses": str,
    "calib": str,
    "times": str,
    "bin_columns": int,
    "dataloader": str,
    "data": str,
    "topic": str,
    "frames": str,
}
"""Each ``[[dataset]]`` key's TOML type."""

TYPE_NAMES = {str: "a string", int: "an integer", list: "an array", dict: "a table", bool: "a boolean"}


class DatasetEntry(FrameSelection):
    """One ``[[dataset]]`` table: a name and ``run``'s data options (``data_root`` + ``seq``, or
    ``folder`` (+ ``poses``, ``times``, ``calib``), or ``dataloader`` + ``data`` (+ ``topic``)),
    optionally ``frames = "A:B"``; the strides are the suite's."""

    name: str

    @field_validator("name")
    @classmethod
    def _folder_name(cls, name: str) -> str:
        if not DATASET_NAME.fullmatch(name):
            raise ValueError("letters, digits, '.', '_' and '-' only (it names the dataset's folder)")
        return name

    @field_validator("dataloader")
    @classmethod
    def _known_loader(cls, loader: str | None) -> str | None:
        from vcr_odom.data.kiss_loaders import LOADERS

        if loader is not None and loader not in LOADERS:
            raise ValueError(f"not a loader{_closest(loader, LOADERS)}; one of {', '.join(LOADERS)}")
        return loader

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
    ``+loops`` for ``vcr-odom map`` cells; ``consult`` and ``device`` apply to the methods that take them
    (``device`` also to a ``+loops`` cell's loop network)."""

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
            raise ValueError(f"one of {', '.join(CONSULT_CHOICES)}{_closest(consult, CONSULT_CHOICES)}")
        return consult

    @field_validator("device")
    @classmethod
    def _known_device(cls, device: str) -> str:
        if device not in DEVICES:
            raise ValueError(f"one of {', '.join(DEVICES)}{_closest(device, DEVICES)}")
        return device

    @model_validator(mode="after")
    def _unique_names(self) -> SuiteSpec:
        names = [dataset.name for dataset in self.dataset]
        twice = sorted({name for name in names if names.count(name) > 1})
        if twice:
            raise ValueError(f"dataset names must differ (each names a folder): {', '.join(twice)} twice")
        return self


UTF8_BOM = b"\xef\xbb\xbf"


def load_suite(path: str | Path) -> SuiteSpec:
    """The suite in ``path``; a ConfigError that names the file (and the key) for any mistake.

    A UTF-8 byte-order mark (Windows editors write one; ``tomllib`` refuses it as "Invalid statement
    at line 1, column 1") is read past, with a warning that names it."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such suite file") from None
    except OSError as error:
        raise ConfigError(f"{path}: cannot read the suite file ({error})") from None
    if raw.startswith(UTF8_BOM):
        warnings.warn(
            f"{path}: starts with a UTF-8 byte-order mark (BOM); read without it", DataWarning, stacklevel=2
        )
        raw = raw[len(UTF8_BOM) :]
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as error:
        line = raw[: error.start].count(b"\n") + 1
        raise ConfigError(
            f"{path}:{line}: not UTF-8 text (byte 0x{raw[error.start]:02x}); a suite file is UTF-8 TOML"
        ) from None
    try:
        data: dict[str, Any] = tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{path}: not valid TOML ({error})") from None
    try:
        check_types(data)
        suite = SuiteSpec(**data)
    except ConfigError as error:
        raise ConfigError(f"{path}: {error}") from None
    base = path.resolve().parent
    return suite.with_changes(dataset=[d.resolved(base) for d in suite.dataset])


def check_types(data: dict[str, Any]) -> None:
    """Every key known and of its TOML type, before pydantic, which would coerce (``true`` to 1,
    ``"2"`` to 2); a ConfigError naming the key, what it should be and the closest known key."""
    _check_table(data, "", {key: kind[0] for key, kind in SUITE_TYPES.items()})
    for key, kind in SUITE_TYPES.items():
        if len(kind) == 2 and key in data:
            for index, item in enumerate(data[key]):
                where = f"{key}[{index}]" if key != "dataset" else f"[[dataset]] #{index + 1}"
                _check_value(item, where, kind[1])
    for index, table in enumerate(data.get("dataset", [])):
        name = table.get("name")
        label = f"[[dataset]] #{index + 1}" + (f" ({name!r})" if isinstance(name, str) else "")
        _check_table(table, f"{label}: ", DATASET_TYPES, stride_hint=True)


def _check_table(
    table: dict[str, Any], where: str, types: dict[str, type], stride_hint: bool = False
) -> None:
    for key, value in table.items():
        if key not in types:
            if stride_hint and key == "stride":
                continue  # DatasetEntry says why: the suite's strides apply to every dataset
            if stride_hint and key in SUITE_TYPES:  # TOML puts a key written after [[dataset]] in it
                raise ConfigError(
                    f"{where}{key}: a key of the whole suite; write it at the top, before the first [[dataset]]"
                )
            raise ConfigError(f"{where}unknown key {key!r}{_closest(key, types)}; known: {', '.join(types)}")
        _check_value(value, f"{where}{key}", types[key])


def _check_value(value: Any, where: str, expected: type) -> None:
    if isinstance(value, expected) and not (expected is int and isinstance(value, bool)):
        return
    got = TYPE_NAMES.get(type(value), type(value).__name__)
    shown = str(value).lower() if isinstance(value, bool) else repr(value)
    raise ConfigError(f"{where}: expected {TYPE_NAMES[expected]}, got {got} ({shown})")


def _closest(word: str, choices: Any) -> str:
    """`` (did you mean 'x'?)`` for the closest of ``choices``, or nothing."""
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def check_inputs(suite: SuiteSpec, suite_file: Path, *, here: bool = True) -> None:
    """What each cell would find missing only when it runs, checked for all of them before the first:
    every path exists (and is a folder or a file as its key says), and, for cells run ``here`` (not
    on a Ray cluster, whose nodes may differ), every loader's packages are installed and ``device =
    "cuda"`` has CUDA. A ConfigError naming the file, the dataset and the key."""
    for dataset in suite.dataset:
        for key in PATH_KEYS:
            value: Path | None = getattr(dataset, key)
            if value is None:
                continue
            where = f"{suite_file}: dataset {dataset.name!r}: {key} {value}"
            if not value.exists():
                raise ConfigError(f"{where}: does not exist")
            if key in FOLDER_KEYS and not value.is_dir():
                raise ConfigError(f"{where}: is not a folder")
            if key not in FOLDER_KEYS and key != "data" and not value.is_file():
                raise ConfigError(f"{where}: is not a file")
        if here and dataset.dataloader is not None:
            from vcr_odom.data.kiss_loaders import check_loader

            try:
                check_loader(dataset.dataloader)
            except ConfigError as error:
                raise ConfigError(f"{suite_file}: dataset {dataset.name!r}: {error}") from None
    if here and suite.device == "cuda" and any(_uses_device(method) for method in suite.methods):
        import torch

        if not torch.cuda.is_available():
            raise ConfigError(f'{suite_file}: device = "cuda", but CUDA is not available here (cpu or auto)')


def _uses_device(method: str) -> bool:
    """Whether a cell of ``method`` runs a network: vcr, or a ``+loops`` cell's loop network."""
    return method.startswith("vcr") or method.endswith("+loops")
