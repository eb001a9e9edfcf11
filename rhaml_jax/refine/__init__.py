"""Iterative refinement (the paper's IR): multi-hypothesis silhouette alignment (`align`).

Public API: `AlignConfig`, `AlignResult`, `align` (see rhaml_jax.refine.align).
"""

from rhaml_jax.refine.alignment import AlignConfig, AlignResult, align

__all__ = ["AlignConfig", "AlignResult", "align"]
