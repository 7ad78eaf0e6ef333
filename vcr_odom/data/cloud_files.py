"""Is a ``.ply``/``.pcd`` file whole? Its header says how much data follows; this checks that it does.

open3d reads a truncated PLY without complaint: it logs to the console and returns as many points as the
header declares, the missing ones filled with whatever was in memory (often zeros: points at the sensor's
origin, which registration then happily matches). So the header is parsed here and the data it declares
is checked against what the file holds, before open3d reads it. Only a header this module understands is
judged; anything else is left to open3d (an unreadable file still fails there, with the file named).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

from vcr_odom.errors import DataError

_PLY_SIZES = {
    "char": 1, "int8": 1, "uchar": 1, "uint8": 1,
    "short": 2, "int16": 2, "ushort": 2, "uint16": 2,
    "int": 4, "int32": 4, "uint": 4, "uint32": 4, "float": 4, "float32": 4,
    "double": 8, "float64": 8,
}  # fmt: skip


@dataclass(frozen=True)
class CloudLayout:
    """What a header promises: ``points`` records after ``offset`` bytes, either ``record_bytes`` each
    (binary) or one text line of ``columns`` numbers each (ascii); ``lines_before`` data lines (ascii) or
    ``bytes_before`` bytes (binary) of other elements come first."""

    points: int
    encoding: str
    offset: int
    record_bytes: int | None
    columns: int
    lines_before: int = 0
    bytes_before: int | None = 0


def _header_end(data: bytes, marker: bytes) -> int | None:
    """Offset just past the header line starting with ``marker``, or None if there is none."""
    start = 0
    while start < len(data):
        stop = data.find(b"\n", start)
        if stop < 0:
            return None
        if data[start:stop].strip().lower().startswith(marker):
            return stop + 1
        start = stop + 1
    return None


def ply_layout(data: bytes) -> CloudLayout | None:
    """The vertex data a PLY header declares, or None for a header this parser does not follow."""
    if not data.startswith(b"ply"):
        return None
    offset = _header_end(data[:65536], b"end_header")
    if offset is None:
        return None
    encoding, elements = None, []  # elements: [name, count, sizes (None for a list property)]
    for raw in data[:offset].decode("ascii", "replace").splitlines()[1:]:
        words = raw.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and len(words) >= 2:
            encoding = "ascii" if words[1] == "ascii" else "binary"
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append([words[1], int(words[2]), []])
        elif words[0] == "property" and elements:
            size = _PLY_SIZES.get(words[1]) if len(words) == 3 else None
            elements[-1][2].append(size)
    names = [element[0] for element in elements]
    if encoding is None or "vertex" not in names:
        return None
    lines_before, bytes_before = 0, 0
    for _name, count, sizes in elements[: names.index("vertex")]:
        lines_before += count
        bytes_before = None if bytes_before is None or None in sizes else bytes_before + count * sum(sizes)
    _, points, sizes = elements[names.index("vertex")]
    record = None if None in sizes else sum(sizes)
    return CloudLayout(points, encoding, offset, record, len(sizes), lines_before, bytes_before)


def pcd_layout(data: bytes) -> CloudLayout | None:
    """The point data a PCD header declares, or None for a header this parser does not follow."""
    offset = _header_end(data[:65536], b"data")
    if offset is None:
        return None
    fields: dict[str, list[str]] = {}
    for raw in data[:offset].decode("ascii", "replace").splitlines():
        words = raw.split()
        if words and not words[0].startswith("#"):
            fields[words[0].upper()] = words[1:]
    try:
        sizes = [int(v) for v in fields["SIZE"]]
        counts = [int(v) for v in fields.get("COUNT", ["1"] * len(sizes))]
        if "POINTS" in fields:
            points = int(fields["POINTS"][0])
        else:
            points = int(fields["WIDTH"][0]) * int(fields["HEIGHT"][0])
        encoding = fields["DATA"][0].lower()
    except (KeyError, IndexError, ValueError):
        return None
    if len(counts) != len(sizes) or encoding not in ("ascii", "binary", "binary_compressed"):
        return None
    record = sum(size * count for size, count in zip(sizes, counts, strict=True))
    return CloudLayout(points, encoding, offset, record, sum(counts))


def check_cloud_file(path: Path, data: bytes) -> None:
    """DataError naming ``path`` when its data is shorter than its header declares (a truncated copy or
    download) or its text data ends inside a record; nothing for a whole file or an unknown header."""
    suffix = path.suffix.lower()
    layout = ply_layout(data) if suffix == ".ply" else pcd_layout(data) if suffix == ".pcd" else None
    if layout is None or layout.points == 0:
        return
    body = data[layout.offset :]
    declared = f"its header declares {layout.points} points"
    if layout.encoding == "ascii":
        _check_text(path, body, layout, declared)
    elif layout.encoding == "binary_compressed":
        if len(body) < 8:
            raise DataError(f"{path}: truncated: {declared} but the compressed data is missing")
        compressed, _ = struct.unpack("<II", body[:8])
        if len(body) - 8 < compressed:
            raise DataError(
                f"{path}: truncated: {declared}, {compressed} compressed bytes, but only "
                f"{len(body) - 8} bytes follow the header"
            )
    elif layout.record_bytes is not None and layout.bytes_before is not None:
        needed = layout.bytes_before + layout.points * layout.record_bytes
        if len(body) < needed:
            whole = max(0, len(body) - layout.bytes_before) // layout.record_bytes
            raise DataError(
                f"{path}: truncated: {declared} ({needed} bytes of data) but only {len(body)} bytes "
                f"follow the header (about {whole} whole points); the file was cut short"
            )


def _check_text(path: Path, body: bytes, layout: CloudLayout, declared: str) -> None:
    lines = [line for line in body.split(b"\n") if line.strip()]
    available = len(lines) - layout.lines_before
    if available < layout.points:
        raise DataError(
            f"{path}: truncated: {declared} but only {max(available, 0)} point lines follow the header"
        )
    last = lines[layout.lines_before + layout.points - 1].split()
    if len(last) < layout.columns:
        raise DataError(f"{path}: truncated: the last point line has {len(last)} of {layout.columns} values")
