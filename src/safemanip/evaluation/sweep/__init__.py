"""Experiment sweeps: a named grid of policies x N x selectors x semantics, run cell by cell, resumable, rendered as
the paper's figure and a markdown table from the stored results alone.

  spec.py     the sweep spec (a JSON file; the shipped ones live in ``evaluation/sweeps/``), checked once into a
              ``SweepSpec``: its format is in that module's docstring
  grid.py     the cells a spec makes (a policy's ``Cell``, a planner reference's ``PlannerCell``) and their ids
  store.py    the stored cell results: written, checked when read back, done or not
  runner.py   ``run_sweep``: the cells not stored yet, then the table and figure
  pooling.py  one method's training seeds pooled into one result
  render.py   the table and the figures

Layout of the output folder (default ``results/FOLDER``, the spec's ``folder``, else ``results/NAME``)::

  cells/<cell id>.json         the cell's parameters and summary (written last: its presence = done)
  cells/<cell id>/summary.json the full summary; cells/<cell id>/episodes.csv the per-episode records (not
                               committed: the same command regenerates them)
  NAME.png, NAME.md            the figure and the table, rebuilt from cells/*.json by --render-only
"""
