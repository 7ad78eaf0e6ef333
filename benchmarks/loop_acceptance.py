"""Two replays of one drive set, before and after a change to the loop phase, held to the loop
design's acceptance: one verdict per item, with the drives that decide it. Not a test: run

    .venv/bin/python benchmarks/loop_acceptance.py BEFORE.json AFTER.json [--name "tuning"] [--json OUT]

BEFORE and AFTER are ``benchmarks/loop_replay.py replay ... --json`` outputs on the same recordings
(one drive set: one table). The items, as the design's acceptance states them:

- no drive with no false loop before gains one;
- revisit passages closed, over the set, no fewer than before minus ``--revisit-slack`` (2);
- the median map/odometry ATE ratio no more than ``--ratio-slack`` (0.05) worse;
- a drive without revisits (no revisit passage and no loop kept before; a drive back along its own
  road counts no passage but keeps loops, so it is not one): its map ATE within ``--unchanged-m``
  (1 cm) of before;
- no map worse than its own odometry by more than 5 % plus 1 cm (after; before's are listed too).

Exit status 0 when every item holds, 1 when one fails, 2 on input it cannot read, so a script can
chain it. Drives in one file
and not the other are named and left out.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, NoReturn

from rich.console import Console
from rich.table import Table

WORSE_SHARE = 0.05
WORSE_M = 0.01
"""A map worse than its own odometry by more than this share plus this many metres of ATE fails."""


@dataclass
class Verdict:
    item: str
    holds: bool
    before: str
    after: str
    drives: list[str]
    """The drives that decide the item (the ones that fail it, or that it is measured on)."""


def fail(message: str) -> NoReturn:
    """Bad input: the message on stderr and exit status 2 (1 means an item failed)."""
    print(message, file=sys.stderr)
    raise SystemExit(2)


def load_rows(path: Path) -> dict[str, dict[str, Any]]:
    """A replay's rows by sequence; a clear error for a file that is not one."""
    try:
        rows = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as error:
        fail(f"{path}: not a readable loop_replay.py --json file ({error})")
    needed = {"sequence", "odometry_ate_m", "map_ate_m", "revisit_passages", "passages_closed"}
    if not isinstance(rows, list) or not all(isinstance(r, dict) and needed <= r.keys() for r in rows):
        fail(f"{path}: expected loop_replay.py replay --json rows with {', '.join(sorted(needed))}")
    return {str(row["sequence"]): row for row in rows}


def map_worse(row: dict[str, Any]) -> bool:
    return row["map_ate_m"] > (1 + WORSE_SHARE) * row["odometry_ate_m"] + WORSE_M


def ratio(row: dict[str, Any]) -> float:
    return row["map_ate_m"] / row["odometry_ate_m"] if row["odometry_ate_m"] > 0 else 1.0


def verdicts(
    before: dict[str, dict[str, Any]],
    after: dict[str, dict[str, Any]],
    *,
    revisit_slack: int = 2,
    ratio_slack: float = 0.05,
    unchanged_m: float = 0.01,
) -> list[Verdict]:
    """The acceptance items on the drives both replays hold."""
    drives = sorted(before.keys() & after.keys())
    if not drives:
        fail("the two replays share no drive")
    pairs = [(before[d], after[d]) for d in drives]
    gained = [
        d
        for d, (b, a) in zip(drives, pairs, strict=True)
        if not b.get("false_closures") and a.get("false_closures")
    ]
    false_before = sum(b.get("false_closures", 0) for b, _ in pairs)
    false_after = sum(a.get("false_closures", 0) for _, a in pairs)
    closed_before = sum(b["passages_closed"] for b, _ in pairs)
    closed_after = sum(a["passages_closed"] for _, a in pairs)
    passages = sum(b["revisit_passages"] for b, _ in pairs)
    lost = [d for d, (b, a) in zip(drives, pairs, strict=True) if a["passages_closed"] < b["passages_closed"]]
    median_before = statistics.median(ratio(b) for b, _ in pairs)
    median_after = statistics.median(ratio(a) for _, a in pairs)
    quiet = [
        d
        for d, (b, _) in zip(drives, pairs, strict=True)
        if b["revisit_passages"] == 0 and not b.get("accepted")
    ]
    moved = [d for d in quiet if abs(after[d]["map_ate_m"] - before[d]["map_ate_m"]) > unchanged_m]
    worse_before = [d for d, (b, _) in zip(drives, pairs, strict=True) if map_worse(b)]
    worse_after = [d for d, (_, a) in zip(drives, pairs, strict=True) if map_worse(a)]
    return [
        Verdict(
            "no drive with 0 false loops gains one", not gained, str(false_before), str(false_after), gained
        ),
        Verdict(
            f"revisits closed >= before - {revisit_slack}",
            closed_after >= closed_before - revisit_slack,
            f"{closed_before}/{passages}",
            f"{closed_after}/{passages}",
            lost,
        ),
        Verdict(
            f"median map/odometry ratio <= before + {ratio_slack:g}",
            median_after <= median_before + ratio_slack,
            f"{median_before:.2f}",
            f"{median_after:.2f}",
            [],
        ),
        Verdict(
            f"drives without revisits unchanged (<= {100 * unchanged_m:g} cm)",
            not moved,
            f"{len(quiet)} drives",
            f"{len(quiet) - len(moved)} unchanged",
            moved,
        ),
        Verdict(
            f"no map worse than its odometry by > {100 * WORSE_SHARE:g} % + {100 * WORSE_M:g} cm",
            not worse_after,
            str(len(worse_before)),
            str(len(worse_after)),
            worse_after,
        ),
    ]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("before", type=Path, help="loop_replay.py replay --json, before the change")
    parser.add_argument("after", type=Path, help="the same recordings replayed after it")
    parser.add_argument("--name", default="", help="the drive set's name, for the table's title")
    parser.add_argument("--revisit-slack", type=int, default=2)
    parser.add_argument("--ratio-slack", type=float, default=0.05)
    parser.add_argument("--unchanged-m", type=float, default=0.01)
    parser.add_argument("--json", type=Path, help="also write the verdicts here")
    args = parser.parse_args()
    before, after = load_rows(args.before), load_rows(args.after)
    console = Console()
    for label, only in (("before", before.keys() - after.keys()), ("after", after.keys() - before.keys())):
        if only:
            console.print(f"only in {label}, left out: {', '.join(sorted(only))}")
    found = verdicts(
        before,
        after,
        revisit_slack=args.revisit_slack,
        ratio_slack=args.ratio_slack,
        unchanged_m=args.unchanged_m,
    )
    table = Table(
        title=f"loop acceptance{': ' + args.name if args.name else ''} ({len(before.keys() & after.keys())} drives)"
    )
    for header in ("item", "holds", "before", "after", "drives deciding it"):
        table.add_column(header)
    for verdict in found:
        holds = "[green]yes[/green]" if verdict.holds else "[red]no[/red]"
        table.add_row(verdict.item, holds, verdict.before, verdict.after, ", ".join(verdict.drives) or "-")
    console.print(table)
    if args.json:
        temporary = args.json.with_name(args.json.name + ".tmp")
        temporary.write_text(json.dumps([asdict(v) for v in found], indent=1))
        temporary.replace(args.json)
    sys.exit(0 if all(v.holds for v in found) else 1)


if __name__ == "__main__":
    main()
