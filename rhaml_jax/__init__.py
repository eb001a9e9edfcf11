"""rhaml_jax: marker-less multi-robot mutual localization (RHAML) in JAX.

Public API: `camera`, `frames`, `metrics` (geometry), `robots.load_robot` (models), and the
stage packages as they land. Errors from bad input are `RhamlError`.
"""

from rhaml_jax import camera, frames, metrics
from rhaml_jax.errors import RhamlError

__all__ = ["camera", "frames", "metrics", "RhamlError"]
