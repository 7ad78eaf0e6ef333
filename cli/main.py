"""The ``vcr-odom`` command: a thin click group; every command lives in its own module."""

from __future__ import annotations

import click

from vcr_odom.cli.compare import compare
from vcr_odom.cli.demo import demo
from vcr_odom.cli.evaluate import evaluate
from vcr_odom.cli.map import map_command
from vcr_odom.cli.options import FriendlyGroup
from vcr_odom.cli.progress import EXIT_CODES_HELP, show_warnings_on_console
from vcr_odom.cli.run import run
from vcr_odom.cli.synth import synth
from vcr_odom.cli.train import cache, pretrain_command, train_command


@click.group(
    cls=FriendlyGroup, context_settings={"help_option_names": ["-h", "--help"]}, epilog=EXIT_CODES_HELP
)
@click.version_option(package_name="vcr-odom")
def cli() -> None:
    """LiDAR odometry with VCR-Net and classical baselines, scored honestly against ground truth."""
    show_warnings_on_console()


for command in (run, map_command, evaluate, compare, synth, demo, cache, pretrain_command, train_command):
    cli.add_command(command)

if __name__ == "__main__":
    cli()
