"""The benchmark as a package command (``safemanip bench``): the layer above ``evaluation`` and below ``cli``.

``benchmark.json`` (package data, read by ``benchmark.py``) lists once what used to be copied between a bash queue,
a promotion script and the sweep code: the 18 settings, the training seeds, the recipe every run shares, the budget,
the seed block that chooses each run's final or best policy and the blocks the sweeps report on.

  benchmark.py   the typed loader and its one checker
  runs.py        what a runs folder holds for each run (missing, started, partial, finished, promoted)
  train.py       the runs, one after another here or one Ray task each on a cluster, resumable
  promote.py     final or best of each finished run, chosen on the selection block, into the policies folder
  sweeps.py      the shipped sweeps on their reporting blocks
  verdict.py     the rule that turns two methods' stored cells into better / tied / worse, and a finding's verdict
  findings.py    the status and findings blocks of docs/results.md
  status.py      one line per run and per sweep, from the records
"""
