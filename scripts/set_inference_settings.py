"""Change how a trained VCR-Net weight file runs at inference, without touching its tensors.

Some settings of the stored configuration act only at inference (the point count and the input
crop, the pose head's robust rounds and consensus, the pointer sharpening: ``INFERENCE_FIELDS``).
Choosing them on figures is part of shipping a file, so this writes a copy with new values and
records the change in its metadata (``inference_settings``: what was set and the note given,
appended to earlier entries):

    .venv/bin/python scripts/set_inference_settings.py weights/vcr-default.safetensors \\
        --set input_max_range=80 --note "chosen on kitti-sample frames 0-39 and synthetic seeds 201-204" \\
        [--out OTHER.safetensors]

Without ``--out`` the file is replaced atomically. Architecture fields are refused by name.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from vcr_odom.errors import ConfigError
from vcr_odom.model.config import parse_inference_setting


def parse_assignments(assignments: list[str]) -> dict[str, object]:
    changes: dict[str, object] = {}
    for assignment in assignments:
        name, equals, value = assignment.partition("=")
        if not equals or not value.strip():
            raise SystemExit(f"--set expects NAME=VALUE; got {assignment!r}")
        try:
            changes[name.strip()] = parse_inference_setting(name.strip(), value.strip())
        except ConfigError as error:
            raise SystemExit(f"--set {assignment}: {error}") from None
    return changes


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("weights", type=Path)
    parser.add_argument("--set", dest="assignments", action="append", required=True, metavar="NAME=VALUE")
    parser.add_argument("--note", required=True, help="why: the data the values were chosen on")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    changes = parse_assignments(args.assignments)

    from vcr_odom.errors import VcrOdomError
    from vcr_odom.model.network import VCRNet
    from vcr_odom.model.weights import read_weights, save_weights

    try:
        tensors, config, metadata = read_weights(args.weights)
        new_config = config.with_changes(**changes)
    except VcrOdomError as error:
        raise SystemExit(f"error: {error}") from error
    model = VCRNet(config)
    model.load_state_dict(tensors)
    described = ", ".join(f"{name}={getattr(new_config, name)}" for name in changes)
    history = [entry for entry in (metadata.get("inference_settings"),) if entry]
    metadata["inference_settings"] = "; ".join([*history, f"{described} ({args.note})"])
    written = save_weights(args.out or args.weights, model, new_config, metadata)
    print(f"{written}: {described}", file=sys.stderr)


if __name__ == "__main__":
    main()
