"""The shape-based generative model of chapter 4: view mapping, tensor core, identity manifold.

``y(α, Θ) = 𝒜 ×₃ i(α) ×₂ Ψ(Θ)`` (eq. 4.18): :class:`RBFViewMapping` gives Ψ(Θ),
:class:`TensorCore` holds 𝒜 and the identity vectors iᵏ, :class:`IdentityManifold` gives i(α),
and :class:`GenerativeShapeModel` ties them together with the vehicle metadata and checkpoints.
"""

from torch_atr.model.generative import GenerativeShapeModel, fine_tune_widths, load_checkpoint
from torch_atr.model.identity import IdentityManifold, dissimilarity, shortest_closed_path
from torch_atr.model.rbf import RBFViewMapping, rbf_features, ridge_hat
from torch_atr.model.tensor import TensorCore, mode_basis, mode_product, unfold

__all__ = [
    "GenerativeShapeModel", "IdentityManifold", "RBFViewMapping", "TensorCore", "dissimilarity",
    "fine_tune_widths", "load_checkpoint", "mode_basis", "mode_product", "rbf_features", "ridge_hat",
    "shortest_closed_path", "unfold",
]
