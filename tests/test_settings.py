"""The configuration base: bad values name the field, dumps round-trip, copies are re-validated."""

from __future__ import annotations

import json

import pytest
from pydantic import Field, model_validator

from vcr_odom.errors import ConfigError
from vcr_odom.settings import Settings


class Example(Settings):
    size: int = Field(default=4, ge=1)
    scale: float = Field(default=1.5, gt=0)
    name: str | None = None

    @model_validator(mode="after")
    def _size_fits_scale(self) -> Example:
        if self.size * self.scale > 100:
            raise ValueError(f"size * scale must be <= 100; got {self.size * self.scale:g}")
        return self


def test_bad_value_names_the_class_and_the_field() -> None:
    with pytest.raises(ConfigError, match=r"Example: size: .*greater than or equal to 1 \(got 0\)"):
        Example(size=0)


def test_cross_field_rule_is_reported_without_pydantic_noise() -> None:
    with pytest.raises(ConfigError, match=r"^Example: size \* scale must be <= 100; got 150$"):
        Example(size=100, scale=1.5)


def test_unknown_field_is_rejected() -> None:
    with pytest.raises(ConfigError, match="sise"):
        Example(sise=3)
    with pytest.raises(ConfigError, match="a dict is needed; got list"):
        Example.from_dict([1, 2])


def test_json_round_trip_and_frozen() -> None:
    config = Example(size=7, name="x")
    again = Example.from_dict(json.loads(json.dumps(config.to_dict())))
    assert again == config
    with pytest.raises(Exception, match="frozen"):
        config.size = 3  # type: ignore[misc]


def test_with_changes_validates_again() -> None:
    assert Example().with_changes(size=9).size == 9
    with pytest.raises(ConfigError, match="size"):
        Example().with_changes(size=-1)


def test_any_settings_model_writes_a_toml_file_it_reads_back(tmp_path) -> None:
    """The file a user edits: a title line, each field's value (an optional one left out of TOML, which
    has no null, is not a field the file sets), and an unknown field named with the command that lists
    the fields."""

    class Titled(Example):
        toml_title = "example settings"
        toml_listed_by = "example --dump-config"

    path = tmp_path / "example.toml"
    text = Titled(size=6, scale=2.0).dump_toml()
    assert text.startswith("# example settings\n") and "\nsize = 6\n" in text and "\nscale = 2.0\n" in text
    assert "\n# name is unset" in text
    path.write_text(text)
    assert Titled.from_toml(path) == {"size": 6, "scale": 2.0}
    assert Titled(**Titled.from_toml(path)) == Titled(size=6, scale=2.0)
    path.write_text("sise = 6\n")
    with pytest.raises(
        ConfigError, match=r"example\.toml: unknown setting\(s\) sise; `example --dump-config`"
    ):
        Titled.from_toml(path)
