"""The zoom-in stage: a small AMLNet (task "zoom") on a crop around AMLNet's estimate.

Why: at 128 x 160 the whole-image network sees the robot 5-40 px wide and learns its position
but not its heading (BENCHMARKS.md: the heading outputs stay at the mean predictor), while the
same kind of network learns the heading within minutes from a crop in which the robot fills
the input. The crop is taken where the first estimate puts the robot, at a scale set by its
range, from the full-resolution image (as DeepIM's zoom-in does for refinement).

Geometry (DESIGN.md section 2 frames; camera at height h looking along the robot's x axis):
the crop is centred on the projection of the point (x^, y^, zoom_centre_z_m) of the estimate
(x^, y^) and is zoom_factor * zoom_length_m * fx / x^ pixels wide, resampled to the network's
S x S input. The network regresses, relative to the estimate's range r^ and bearing b^:

    t = (log(r / r^), b - b^, psi - b^)     (angles wrapped)

which are what the crop shows whatever the range (the robot's size in the crop is r^ / r of
its nominal size, its offset from the centre is b - b^, and its look depends on psi - b).
`apply_correction` turns t back into (x, y, psi).

Host side (NumPy + OpenCV, like the data pipeline): `crop_transform`, `zoom_crop`,
`correction_targets`, `apply_correction`, `mirror_average` (test-time mirroring), and
`ZoomSource` (training examples, a pure function of (seed, index)), the flip calibration
(`FlipCalibration`: its front/back ranking made a probability). Pure JAX: the network itself.
"""

from rhaml_jax.crop import MIN_RANGE_M
from rhaml_jax.zoom._correction import (ZoomCorrection, apply_correction, box, correction_targets, crop_transform,
                                        decode_correction, mirror_average, zoom_crop)
from rhaml_jax.zoom._flip_calibration import (FlipCalibration, calibration_metrics, fit_flip_calibration, flip_probability,
                                              write_flip_calibration)
from rhaml_jax.zoom._source import ZoomJitter, ZoomSource, zoom_batch_sources

__all__ = ["ZoomCorrection", "ZoomJitter", "ZoomSource", "apply_correction", "box", "decode_correction",
           "correction_targets", "crop_transform", "mirror_average", "zoom_batch_sources", "zoom_crop", "MIN_RANGE_M",
           "FlipCalibration", "calibration_metrics", "fit_flip_calibration", "flip_probability",
           "write_flip_calibration"]
