"""Synthetic data and evaluation scenarios, written and read as BOP (images) and TUM (trajectories).

- `training_sample(mesh, camera, seed, index)`: one training image, a pure function of (seed, index).
- `circle`, `sine`, `rendezvous`, `noisy_odometry`: DESIGN.md section 3's trajectories and noise.
- `read_bop`, `load_rgb`, `load_mask`, `load_bop_model`: read ours and other tools' BOP sets;
  `write_dataset_header`: a BOP set's camera.json and models/ (the robot in millimetres).
- `read_tum`, `write_tum`: trajectory files.
- `write_training_set`, `write_scenario`: whole data sets (what `python -m rhaml_jax.generate` runs);
  `mix_sets`: several training sets of one robot as one (symlinks).
- `AppearanceConfig`: the v2 appearance randomisation's factors and ranges (`SynthConfig.appearance`;
  None gives the v1 data); `HeldoutConfig`, `check_heldout`, `write_heldout`: the held-out
  appearance benchmark, outside every training range; `OOD_VALIDATION`, `check_apart`: the
  out-of-distribution validation set's settings (`write_heldout(..., heldout=OOD_VALIDATION)`),
  outside training and apart from the held-out set; `sample_look`, `sample_heldout_look`: one
  image's look (a pure function of (seed, index)).
"""

from rhaml_jax.data._bop import (BopFrame, bop_model_path, load_bop_model, load_mask, load_rgb, read_bop, scene_folders,
                                 write_dataset_header)
from rhaml_jax.data._synth import Sample, SynthConfig, sample_rng, scenario_frame, training_sample
from rhaml_jax.data._trajectories import Room, circle, noisy_odometry, rendezvous, sine
from rhaml_jax.data._tum import read_tum, write_tum
from rhaml_jax.data._writer import write_scenario, write_training_set

__all__ = [
    "BopFrame", "bop_model_path", "Room", "Sample", "SynthConfig", "circle", "load_bop_model", "load_mask", "load_rgb",
    "noisy_odometry", "read_bop", "read_tum", "rendezvous", "sample_rng", "scenario_frame",
    "scene_folders", "sine", "training_sample", "write_dataset_header", "write_scenario", "write_training_set", "write_tum",
]

from rhaml_jax.data._augment import AugmentConfig, augment  # noqa: E402
from rhaml_jax.data._pipeline import (Batch, FromDisk, OnTheFly, amlnet_batch_source, make_batch_fn,  # noqa: E402
                                      network_image)

from rhaml_jax.data._cache import ImageCache  # noqa: E402

__all__ += ["ImageCache", "AugmentConfig", "augment", "Batch", "FromDisk", "OnTheFly", "amlnet_batch_source", "make_batch_fn",
            "network_image"]

from rhaml_jax.data._appearance import (OOD_VALIDATION, AppearanceConfig, HeldoutConfig, Look, check_apart,  # noqa: E402
                                        check_heldout, deferred_checks, sample_heldout_look, sample_look,
                                        sample_paint)
from rhaml_jax.data._writer import write_heldout  # noqa: E402

__all__ += ["OOD_VALIDATION", "AppearanceConfig", "HeldoutConfig", "Look", "check_apart", "check_heldout", "deferred_checks", "sample_heldout_look", "sample_look", "sample_paint", "write_heldout"]

from rhaml_jax.data._writer import write_sequence  # noqa: E402  (scenes given by their poses, e.g. map fusion's)

__all__ += ["write_sequence"]

from rhaml_jax.data._mix import mix_sets  # noqa: E402

__all__ += ["mix_sets"]
