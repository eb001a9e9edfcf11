"""rhaml_jax: marker-less multi-robot mutual localization (RHAML) in JAX.

Public API: `camera`, `frames`, `metrics` (geometry), `robots.load_robot` (models), and the
stage packages as they land. Errors from bad input are `RhamlError`. `tune_allocator()` (call it
first) keeps XLA's large buffers from page-faulting anew at every step on Linux;
`enable_compile_cache()` keeps compiled programs on disk for the next run.
"""

from rhaml_jax import camera, frames, metrics
from rhaml_jax.allocator import tune_allocator
from rhaml_jax.compile_cache import enable_compile_cache
from rhaml_jax.errors import RhamlError

__all__ = ["camera", "enable_compile_cache", "frames", "metrics", "RhamlError", "tune_allocator"]
