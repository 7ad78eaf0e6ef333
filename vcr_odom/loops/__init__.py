"""Loop closure for ``vcr-odom map``: pose-graph nodes recorded during the odometry (``nodes``),
candidates within the odometry's drift (``candidates``, ``drift``), registration and verification
(``verify``), the robust pose graph (``graph``), and the pipeline into a result folder (``pipeline``).

Submodules are imported where used: importing this package loads neither open3d nor torch.
"""
