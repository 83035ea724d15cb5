"""torch_atr: joint target tracking and recognition with a shape-based generative model.

The package follows the method of the thesis in ``shared/mission`` (chapters 4-6):
vehicles -> pose -> rendering -> shape encoding -> model (rbf, tensor, identity, generative) ->
segmentation -> tracking (motion, observation, appearance, filter) -> data -> evaluation -> viz.

Rendered silhouettes and model outputs are torch tensors; frames and masks that come from
OpenCV (sequences, segmentation) are NumPy arrays.

Dimension letters used in every docstring:

    N   queries or particles (a batch)
    K   training vehicles
    V   views (θ, φ pairs)
    Nc  RBF kernel centres on the view hemisphere
    P   Nc + 4, the length of Ψ(Θ) = [κ(‖u − u(Υₗ)‖)…, 1, u]
    H×W template size in pixels; d = H·W pixels of a flattened template
    r   rank of the truncated pixel basis (d -> r)
    M   points (vertices) of a mesh or point set; hypotheses of a blind start
    L   the tracker's likelihood grid (L x L, L divides the template size)

Angles are radians. Frames and conventions: ``shared/mission/METHOD.md``.
"""

__version__ = "0.1.0"
