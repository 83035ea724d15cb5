"""Experiments of the thesis's chapter 6, reproducible by one command each.

    python -m torch_atr.experiments sensiac-like --out DIR [--quick] [--init blind|truth] [--workers N]

:mod:`~torch_atr.experiments.sensiac_like` runs the grid (resumable, in worker processes) and
:mod:`~torch_atr.experiments.report` writes ``report.md``, ``results.json`` and the figures.
"""
