"""Loop closure for ``vcr-odom map``, as pose-graph SLAM: keyframe nodes and submaps recorded during
the odometry (``nodes``), candidates gated by the odometry's propagated uncertainty (``candidates``),
verification as a measurement with its information (``verify``), pairwise consistency and the solve
(``graph``), gravity priors from walls and ground (``gravity``), every threshold in one model
(``settings``), and the pipeline into a result folder (``pipeline``). docs/architecture.md draws it.

Submodules are imported where used: importing this package loads neither open3d nor torch.
"""
