"""Experiments of the thesis's chapter 6, reproducible by one command each, or all by one.

    python -m torch_atr.experiments all --out DIR [--quick] [--init blind|truth] [--workers N]
    python -m torch_atr.experiments sensiac-like --out DIR [--quick | --full] [--init blind|truth] [--workers N]
    python -m torch_atr.experiments unseen --out DIR [--quick] [--init blind|truth] [--workers N]
    python -m torch_atr.experiments studies --out DIR [--quick] [--workers N]
    python -m torch_atr.experiments visible --out DIR [--quick] [--workers N]

:mod:`~torch_atr.experiments.sensiac_like` runs a grid of sequences (resumable, in worker
processes), :mod:`~torch_atr.experiments.report` writes the SENSIAC-like ``report.md``,
``results.json`` and figures, :mod:`~torch_atr.experiments.unseen` the held-out meshes' report,
:mod:`~torch_atr.experiments.studies` the one-change-at-a-time studies beyond the thesis, and
:mod:`~torch_atr.experiments.visible` the visible-band experiment (thesis 6.3), and
:mod:`~torch_atr.experiments.combined` the one report of them all.
"""
