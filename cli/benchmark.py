"""``vcr-odom benchmark SUITE.toml``: datasets x methods x strides, each cell a result folder, on a
process pool or a Ray cluster, resumable; one summary table."""

from __future__ import annotations

from pathlib import Path

import click
from rich.progress import Progress
from rich.table import Table

from vcr_odom.cli.options import results_dir_option
from vcr_odom.cli.progress import EXIT_CODES_HELP, bar_columns, console, exit_interrupted, interrupt_label

SUITE_HELP = """\b
A suite file (TOML):
  methods = ["kiss-icp", "vcr"]      # as run spells them; "vcr+loops": a map cell
  strides = [1, 5]
  consult = "on-doubt"               # optional, for the polished global methods
  device = "cpu"                     # optional, for vcr (cpu, cuda, auto)
  [[dataset]]
  name = "kitti-03"                  # names the dataset's folder
  data_root = "/data/kitti"          # + seq; or folder (+ poses, times, calib);
  seq = "03"                         # or dataloader + data (+ topic); frames = "A:B"
Relative paths are taken from the suite file's folder."""


@click.command("benchmark", epilog=SUITE_HELP + "\n\n" + EXIT_CODES_HELP)
@click.argument("suite_file", type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--out",
    type=click.Path(path_type=Path, file_okay=False),
    default=None,
    help="The suite's folder [default: RESULTS_DIR/benchmark_<suite file's name>]. Rerunning into the "
    "same folder skips complete cells and reruns partial or failed ones.",
)
@results_dir_option(
    "Where result folders are written, as for run, compare and map: the suite's folder goes "
    "under it unless --out names one."
)
@click.option(
    "--jobs",
    type=click.IntRange(min=1, max=512),
    default=1,
    show_default=True,
    help="Cells at a time on this machine (a process pool); each cell gets cores / jobs threads.",
)
@click.option(
    "--ray",
    "ray_address",
    default=None,
    metavar="local|ADDRESS",
    help="Run the cells as Ray tasks: 'local' starts a local cluster of --jobs CPUs, an address joins "
    "one ('auto', 'ray://host:10001'). Needs vcr-odom[ray]; data and --out on a file system every node sees.",
)
def benchmark(
    suite_file: Path, out: Path | None, results_dir: Path, jobs: int, ray_address: str | None
) -> None:
    """Run a benchmark suite: every dataset x method x stride as `run` (or `map`) would, then
    summary.json, summary.md (per dataset, the mean over datasets and the pooled devkit drift) and plots."""
    from vcr_odom.suite.suite import planned, run_plan

    folder = out or results_dir / f"benchmark_{suite_file.stem}"
    with planned(suite_file, folder, ray=ray_address) as plan:
        cells, todo = plan.cells, plan.todo
        if len(todo) < len(cells):
            console.print(f"{len(cells) - len(todo)} of {len(cells)} cells complete in {folder}: skipped")
        for key, reason in plan.reruns.items():
            console.print(f"{key}: {reason}", highlight=False)
        with Progress(*bar_columns("last"), console=console) as progress:
            task = progress.add_task("cells", total=len(todo), last="")

            def on_cell(cell: object, row: dict[str, object]) -> None:
                progress.update(
                    task,
                    advance=1,
                    last=f"{row['dataset']} {row['method']} x{row['stride']}: {row['status']}",
                )

            outcome = run_plan(plan, jobs=jobs, ray=ray_address, on_cell=on_cell)
    console.print(summary_table(outcome.rows))
    failed = [row for row in outcome.rows if row["status"] == "failed"]
    console.print(
        f"summary in {folder / 'summary.md'} ({len(outcome.ran)} cells run, {len(outcome.skipped)} skipped)"
    )
    if outcome.interrupted:
        exit_interrupted(
            f"Interrupted ({interrupt_label()}); complete cells are kept. Rerun the same command to finish the rest."
        )
    if failed:
        raise click.ClickException(f"{len(failed)} cell(s) failed; reasons in {folder / 'summary.md'}")


def summary_table(rows: list[dict[str, object]]) -> Table:
    from vcr_odom.suite.summary import COLUMNS, format_cell

    table = Table(title="benchmark")
    table.add_column("dataset")
    for header, _, _ in COLUMNS:
        table.add_column(header, justify="left" if header in ("method", "status") else "right")
    for row in rows:
        table.add_row(str(row["dataset"]), *(format_cell(row, key, fmt) for _, key, fmt in COLUMNS))
    return table
