"""Loop closure for ``vcr-odom map``, as pose-graph SLAM, a stage a module (``nodes``, ``candidates``,
``verify``, ``graph``, ``gravity``, ``settings``, ``pipeline``); docs/architecture.md draws the flow.

Submodules are imported where used: importing this package loads neither open3d nor torch.
"""
