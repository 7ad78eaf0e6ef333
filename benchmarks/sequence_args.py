"""The options every benchmark on one KITTI-layout sequence shares (imported by the scripts beside it)."""

from __future__ import annotations

import argparse
from pathlib import Path


def sequence_parser(doc: str | None) -> argparse.ArgumentParser:
    """A parser with ``--data-root`` (required), ``--seq`` and ``--frames``; ``doc`` is the help text."""
    parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data-root", type=Path, required=True)
    parser.add_argument("--seq", default="00")
    parser.add_argument("--frames", default=None, help="A:B (B exclusive)")
    return parser
