"""``vcr-odom benchmark``: a suite of datasets x methods x strides, each cell a ``run`` (or ``map``)
result folder, spread over a process pool or a Ray cluster, resumable, summarised in one table.

One module per job: :mod:`.spec` (the suite file), :mod:`.cells` (one cell: run it, read its row back
from its folder), :mod:`.executors` (where cells run), :mod:`.summary` (summary.json, summary.md, plots),
:mod:`.suite` (the whole: what to skip, what to run, what to write after each cell).
"""
