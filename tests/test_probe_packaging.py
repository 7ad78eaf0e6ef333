"""Result folders are named after the data they hold (issue 23): two KITTI roots with a sequence 00 no
longer both give ``..._kitti-00_...``, and a name never carries characters a shell or file system mangles."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from vcr_odom.cli.main import cli
from vcr_odom.data import FolderSequence, KissLoaderSequence, KittiSequence, open_sequence
from vcr_odom.errors import DataWarning
from vcr_odom.results import create_result_folder
from vcr_odom.synth import generate_sequence

STAMP = r"\d{8}-\d{6}"


@pytest.fixture(scope="module")
def two_roots(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """Two KITTI-layout roots, each with a 4-frame sequence '00': only their folder names differ."""
    base = tmp_path_factory.mktemp("roots")
    roots = (base / "drive-a", base / "drive-b")
    for seed, root in enumerate(roots):
        generate_sequence(root, seq="00", frames=4, seed=seed)
    return roots


def result_names(results: Path) -> list[str]:
    return sorted(p.name for p in results.iterdir() if not p.is_symlink() and not p.name.startswith("."))


def test_runs_on_two_kitti_roots_get_folders_named_after_each_root(two_roots, tmp_path):
    for root in two_roots:
        args = ["run", "--data-root", str(root), "--seq", "0", "--method", "icp10"]
        result = CliRunner().invoke(cli, [*args, "--results-dir", str(tmp_path)])
        assert result.exit_code == 0, result.output
    first, second = result_names(tmp_path)
    assert re.fullmatch(rf"{STAMP}_run_drive-a-00_icp10", first), first
    assert re.fullmatch(rf"{STAMP}_run_drive-b-00_icp10", second), second


def test_a_kitti_label_names_the_root_as_typed(two_roots, monkeypatch):
    root = two_roots[0]
    assert KittiSequence(root, "00").label == "drive-a-00"
    assert open_sequence(folder=root / "sequences" / "00").label == "drive-a-00"  # found as KITTI
    monkeypatch.chdir(root)
    assert KittiSequence(".", 0).label == "drive-a-00"  # "." is the folder it stands for
    link = root.parent / "my-link"
    link.symlink_to(root, target_is_directory=True)
    assert KittiSequence(link, "00").label == "my-link-00"  # the name the user typed, not the target's


def test_a_scan_folder_and_a_recording_are_labelled_by_their_own_names(tmp_path):
    scans = tmp_path / "Fahrt 2024"
    scans.mkdir()
    for index in range(2):
        np.zeros((10, 4), np.float32).tofile(scans / f"{index}.bin")
    with pytest.warns(DataWarning):
        assert FolderSequence(scans).label == "Fahrt 2024"
    with pytest.warns(DataWarning):
        assert KissLoaderSequence("generic", scans).label == "Fahrt 2024"


def test_a_bag_is_labelled_by_its_stem(tmp_path):
    pytest.importorskip("rosbags")
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store, cloud = get_typestore(Stores.ROS1_NOETIC), "sensor_msgs/msg/PointCloud2"
    types = store.types
    fields = [
        types["sensor_msgs/msg/PointField"](name=name, offset=4 * k, datatype=7, count=1)
        for k, name in enumerate("xyz")
    ]
    header = types["std_msgs/msg/Header"](
        seq=0, stamp=types["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id="lidar"
    )
    points = np.arange(30, dtype=np.float32).reshape(10, 3)
    message = types[cloud](
        header=header, height=1, width=10, fields=fields, is_bigendian=False, point_step=12,
        row_step=120, data=np.frombuffer(points.tobytes(), np.uint8), is_dense=True,
    )  # fmt: skip
    with Writer(tmp_path / "city.loop.bag") as writer:
        connection = writer.add_connection("/points", cloud, typestore=store)
        writer.write(connection, 10**9, store.serialize_ros1(message, cloud))
    with KissLoaderSequence("rosbag", tmp_path / "city.loop.bag") as sequence:
        assert sequence.name == "rosbag/city" and sequence.label == "city.loop"


@pytest.mark.parametrize(
    ("label", "expected"),
    [
        ("run_kitti/00_vcr+kiss-icp", "run_kitti-00_vcr-kiss-icp"),
        ("run_Fahrt ü 2024:03_icp10", "run_Fahrt-2024-03_icp10"),
        ("run_../../etc_icp10", "run_..-..-etc_icp10"),
        ("..", "run"),
        ("ü", "run"),
    ],
)
def test_folder_names_keep_only_safe_ascii(tmp_path, label, expected):
    folder = create_result_folder(tmp_path, label)
    assert folder.parent == tmp_path
    assert re.fullmatch(rf"{STAMP}_{re.escape(expected)}", folder.name), folder.name


def test_a_very_long_label_is_cut_to_a_name_every_file_system_takes(tmp_path):
    folder = create_result_folder(tmp_path, "run_" + "x" * 400 + "_icp10")
    assert folder.is_dir() and len(folder.name) <= 120


# -- the model card ----------------------------------------------------------------------------------

ROOT = Path(__file__).resolve().parents[1]
CARD = ROOT / "weights" / "MODEL_CARD.md"
HUB_SECTIONS = (
    "Model details",
    "Intended use",
    "Out-of-scope use",
    "Training data",
    "Training procedure",
    "Evaluation",
    "Limitations and known failures",
    "Deviations from the paper, and why",
)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_the_model_card_is_short_and_has_the_sections_users_look_for():
    text = CARD.read_text()
    headings = re.findall(r"^## (.+)$", text, flags=re.M)
    assert len(text.splitlines()) <= 350
    assert list(HUB_SECTIONS) == [h for h in headings if h in HUB_SECTIONS]
    assert "Speed on a GPU: never measured" in text  # no invented figure for what no one timed
    listed = [expand(name) for name in re.findall(r"^\| `([^`]+)` \|", text, flags=re.M)]
    files = [name for names in listed for name in names]
    assert {"vcr-default.safetensors", "training/vcr-default-finetune.run.json"} <= set(files)
    assert [name for name in files if not (CARD.parent / name).is_file()] == []


def expand(name: str) -> list[str]:
    """``a.{run,history}.json`` -> ``a.run.json``, ``a.history.json`` (the card's file table)."""
    match = re.search(r"\{([^}]+)\}", name)
    if match is None:
        return [name]
    return [name[: match.start()] + part + name[match.end() :] for part in match.group(1).split(",")]


@pytest.mark.parametrize("document", [CARD, ROOT / "docs" / "results.md"])
def test_links_between_the_documents_reach_a_file_and_a_heading(document):
    for target in re.findall(r"\]\(([^)#\s]+\.md)(?:#([\w-]+))?\)", document.read_text()):
        path, anchor = document.parent / target[0], target[1]
        assert path.is_file(), f"{document.name} links to missing {target[0]}"
        if anchor:
            anchors = {slug(h) for h in re.findall(r"^#+ (.+)$", path.read_text(), flags=re.M)}
            assert anchor in anchors, f"{document.name}: no heading #{anchor} in {target[0]}"


# -- the README ---------------------------------------------------------------------------------------

README = ROOT / "README.md"
SCHEME = re.compile(r"^[a-z][a-z0-9+.-]*:", flags=re.I)  # https:, mailto: (not checked here)


def test_the_readme_is_short_keeps_its_two_commands_and_links_to_files_that_exist():
    text = README.read_text()
    assert len(text.splitlines()) <= 120
    blocks = re.findall(r"^```(?:bash|sh)?\n(.*?)^```", text, flags=re.M | re.S)
    commands = [
        [line.split("#")[0].strip() for line in block.splitlines() if line.strip()] for block in blocks
    ]
    assert ["make demo", "make test"] in commands
    assert {"demo", "test"} <= set(re.findall(r"^([\w-]+):", (ROOT / "Makefile").read_text(), flags=re.M))
    relative = [link for link in re.findall(r"\]\(([^)\s]+)\)", text) if not SCHEME.match(link)]
    assert relative
    for link in relative:
        target, _, anchor = link.partition("#")
        path = README.parent / target if target else README
        assert path.exists(), f"README.md links to missing {target}"
        if anchor and path.suffix == ".md":
            anchors = {slug(h) for h in re.findall(r"^#+ (.+)$", path.read_text(), flags=re.M)}
            assert anchor in anchors, f"README.md: no heading #{anchor} in {target or 'README.md'}"
