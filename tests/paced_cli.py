"""The CLI slowed down for tests that must land a signal or a kill mid-run."""

from __future__ import annotations


def paced_cli_source(pause_s: float) -> str:
    """Python source of ``vcr-odom`` that publishes a checkpoint after every frame and then sleeps
    ``pause_s``: a run of a few frames lasts long enough for a test to stop it in the middle. Its
    ``main`` runs under ``__main__`` only, so the process pools it spawns import it safely."""
    return f"""
import time
from vcr_odom.odometry import outputs
outputs.CHECKPOINT_EVERY_FRAMES = 1
publish = outputs.Checkpoints.__call__
def publish_then_pause(self, index, pose):
    publish(self, index, pose)
    time.sleep({pause_s})
outputs.Checkpoints.__call__ = publish_then_pause
if __name__ == "__main__":
    from vcr_odom.cli.main import main
    main()
"""
