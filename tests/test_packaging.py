"""What a regular (non-editable) install contains: every package, the CLI, and the shipped weights."""

import os
import re
import shutil
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_every_library_package_is_installed_and_cli_is_not_top_level():
    setuptools = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    on_disk = {
        ".".join(init.parent.relative_to(ROOT).parts) for init in (ROOT / "vcr_odom").rglob("__init__.py")
    }
    weight_folders = {
        f"vcr_odom.weights.{folder.name}"
        for folder in (ROOT / "weights").iterdir()
        if folder.is_dir() and folder.name != "__pycache__"
    }
    assert weight_folders, "weights/legacy and weights/training are expected"
    expected = on_disk | {"vcr_odom.cli", "vcr_odom.weights"} | weight_folders
    assert expected == set(setuptools["packages"])
    assert setuptools["package-dir"] == {"vcr_odom.cli": "cli", "vcr_odom.weights": "weights"}


def test_the_wheel_carries_the_shipped_weights_and_the_cli(tmp_path: Path) -> None:
    """A wheel is what ``pip install .`` installs: without the weights in it, ``run`` fails outside
    the source tree. Built from a copy, so setuptools' build/ folder stays out of the checkout."""
    source = tmp_path / "source"
    source.mkdir()
    for name in ("pyproject.toml", "README.md", "LICENSE"):
        shutil.copy2(ROOT / name, source / name)
    for name in ("vcr_odom", "cli", "weights"):
        shutil.copytree(ROOT / name, source / name, ignore=shutil.ignore_patterns("__pycache__"))
    command = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-v"]
    # PYTHONDONTWRITEBYTECODE makes setuptools say "byte-compiling is disabled": the caller's
    # environment, not the packaging, so it stays out of the check for warnings.
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    build = subprocess.run(
        [*command, "-w", str(tmp_path), "."], check=True, capture_output=True, text=True, cwd=source, env=env
    )
    log = build.stdout + build.stderr
    warnings = [line for line in log.splitlines() if re.search(r"warning|would be ignored", line, re.I)]
    assert warnings == []
    (wheel,) = tmp_path.glob("vcr_odom-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    # training runs carried between sessions (a folder with a last.pt): megabytes of checkpoint, not shipped
    carried = [run.parent for run in (ROOT / "weights" / "training").glob("*/last.pt")]
    shipped = {
        p.relative_to(ROOT).as_posix()
        for p in (ROOT / "weights").rglob("*")
        if p.is_file() and "__pycache__" not in p.parts and not any(run in p.parents for run in carried)
    }
    assert {"weights/vcr-default.safetensors", "weights/training/vcr-default.run.json"} <= shipped
    assert {f"vcr_odom/{name}" for name in shipped} - names == set()
    assert "vcr_odom/weights/MODEL_CARD.md" in names
    assert "vcr_odom/cli/main.py" in names
    assert not any(name.startswith(("cli/", "weights/", "tests/")) for name in names)
    assert carried and not any(f"/{run.name}/" in name for run in carried for name in names)


def test_the_library_never_imports_the_cli_or_the_benchmarks():
    """The CLI and benchmarks sit on top of the library; an import the other way would tie a notebook
    user to click and to harness code."""
    import ast

    offenders = []
    for path in (ROOT / "vcr_odom").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            offenders += [
                f"{path.relative_to(ROOT)}: {n}"
                for n in names
                if n.startswith(("vcr_odom.cli", "benchmarks", "cli"))
            ]
    assert offenders == []


def test_modules_stay_small():
    sizes = {
        p.relative_to(ROOT).as_posix(): len(p.read_text().splitlines())
        for p in (ROOT / "vcr_odom").rglob("*.py")
    }
    sizes |= {
        p.relative_to(ROOT).as_posix(): len(p.read_text().splitlines()) for p in (ROOT / "cli").rglob("*.py")
    }
    assert {path: lines for path, lines in sizes.items() if lines > 500} == {}


def test_every_declared_dependency_is_imported():
    """A dependency nothing imports only costs users an install (pykitti pulled in opencv for nothing)."""
    import ast
    import importlib.metadata

    from packaging.requirements import Requirement

    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    declared_names = {Requirement(spec).name.lower().replace("_", "-") for spec in declared}
    imported: set[str] = set()
    for path in [*(ROOT / "vcr_odom").rglob("*.py"), *(ROOT / "cli").rglob("*.py")]:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                imported |= {alias.name.split(".")[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                imported.add(node.module.split(".")[0])
    providers = importlib.metadata.packages_distributions()
    for dist in importlib.metadata.distributions():  # a wheel whose module is one compiled file
        for file in dist.files or []:  # (small_gicp): Python 3.11's mapping looks at .py files only
            if len(file.parts) == 1 and file.suffix in (".so", ".pyd"):
                providers.setdefault(file.name.split(".")[0], []).append(dist.metadata["Name"])
    used = {dist.lower().replace("_", "-") for module in imported for dist in providers.get(module, [])}
    assert declared_names - used == set()
