"""The explicit package list in pyproject.toml must name every package, or a wheel silently drops it."""

import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_library_package_is_installed_and_cli_is_not_top_level():
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    on_disk = {
        ".".join(init.parent.relative_to(ROOT).parts) for init in (ROOT / "vcr_odom").rglob("__init__.py")
    }
    assert on_disk | {"vcr_odom.cli"} == set(setuptools["packages"])
    assert setuptools["package-dir"] == {"vcr_odom.cli": "cli"}
