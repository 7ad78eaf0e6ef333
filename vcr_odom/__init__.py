"""vcr-odom: LiDAR odometry with VCR-Net, ICP polish and honest evaluation against ground truth."""

from importlib import metadata

try:
    __version__ = metadata.version("vcr-odom")
except metadata.PackageNotFoundError:  # running from a source tree that was never installed
    __version__ = "0+unknown"
