"""The 3-D view (``vcr-odom view``, ``run|map --visualize``) on polyscope, the optional ``viz`` extra.

:mod:`~vcr_odom.viewer.scene` holds polyscope (a window, or off-screen EGL for pictures) and the
camera, :mod:`~vcr_odom.viewer.result` reads and draws a finished result folder,
:mod:`~vcr_odom.viewer.live` draws a run as it goes from the odometry's per-frame hook. Nothing here
imports polyscope at import time, so the commands' help and errors work without the extra.
"""
