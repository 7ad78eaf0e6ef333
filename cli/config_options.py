"""Click options generated from a configuration's fields, so that each is written once.

An option takes its default, its bounds (``ge``/``gt``/``le``/``lt`` become an ``IntRange`` or a
``FloatRange``), its choices (a ``Literal``) and its help (the field's ``description``) from the
pydantic field; a ``bool`` becomes a ``--name/--no-name`` switch and a tuple a repeatable option. A
command adds what a field cannot say (another option name, an environment variable, a path that must
exist) through ``names`` and ``extra``.
"""

from __future__ import annotations

import types
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, TypeVar, Union, get_args, get_origin

import click
from pydantic.fields import FieldInfo

from vcr_odom.settings import Settings

F = TypeVar("F", bound=Callable[..., Any])


def config_options(
    config: type[Settings],
    fields: Sequence[str],
    names: Mapping[str, str] | None = None,
    extra: Mapping[str, Mapping[str, Any]] | None = None,
) -> Callable[[F], F]:
    """A decorator adding one option per field of ``config`` in ``fields`` (in that order); the
    command receives each under the field's name. ``names`` maps a field to its option name (default
    ``--field-name``), ``extra`` to more ``click.option`` keywords."""
    names, extra = names or {}, extra or {}

    def decorate(function: F) -> F:
        for name in reversed(fields):
            option = names.get(name, "--" + name.replace("_", "-"))
            function = option_for(config.model_fields[name], name, option, **extra.get(name, {}))(function)
        return function

    return decorate


def option_for(info: FieldInfo, name: str, option: str, **extra: Any) -> Callable[[F], F]:
    """The ``click.option`` of one field (see the module doc)."""
    annotation, multiple = _unwrap(info.annotation)
    default = info.default
    kwargs: dict[str, Any] = {"default": default, "help": info.description}
    kwargs["show_default"] = default is not None and default != ()
    declarations = [option, name]
    if annotation is bool and not multiple:
        declarations = [f"{option}/--no-{option.removeprefix('--')}", name]
    else:
        kwargs["type"] = _click_type(annotation, info)
        kwargs["multiple"] = multiple
    return click.option(*declarations, **(kwargs | dict(extra)))


def _unwrap(annotation: Any) -> tuple[Any, bool]:
    """``X | None`` -> X; ``tuple[X, ...]`` -> (X, multiple)."""
    if get_origin(annotation) in (Union, types.UnionType):
        (annotation,) = [arg for arg in get_args(annotation) if arg is not type(None)]
    if get_origin(annotation) is tuple:
        return get_args(annotation)[0], True
    return annotation, False


def _click_type(annotation: Any, info: FieldInfo) -> Any:
    if get_origin(annotation) is Literal:
        return click.Choice(get_args(annotation))
    if annotation is Path:
        return click.Path(path_type=Path)
    if annotation in (int, float):
        bounds = {
            key: value
            for item in info.metadata
            for key in ("ge", "gt", "le", "lt")
            if (value := getattr(item, key, None)) is not None
        }
        if not bounds:
            return annotation
        kind = click.IntRange if annotation is int else click.FloatRange
        return kind(
            min=bounds.get("ge", bounds.get("gt")),
            max=bounds.get("le", bounds.get("lt")),
            min_open="gt" in bounds,
            max_open="lt" in bounds,
        )
    return annotation
