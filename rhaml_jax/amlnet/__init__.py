"""AMLNet, the initial mutual-localisation network (paper section III-A), in JAX / Flax NNX.

Public API:
- configs: `get_config(name)`, `config_names()`, `AMLNetConfig`, `FrontNetConfig`,
  `config_to_dict` / `config_from_dict`;
- network: `build(cfg, key) -> Net` (graphdef split once; `net.apply(params, batch_stats,
  images)`, `net.train_apply(params, batch_stats, images, key) -> (out, new_batch_stats)`),
  `acn` / `acn_reference` (eqs. 1-2 as pure functions), `decode(out)`;
- loss: `amlnet_loss` (eqs. 3-5, negatives masked out of L_p); the dense head's (config
  head="heatmap") targets, loss and decoding in `rhaml_jax.amlnet.heatmap` (`decode` and the
  training steps dispatch to it);
- counts: `count_params`, `count_macs`, `describe(config_name, bench, batch)`;
- training: `Batch`, `BatchSource` (data interface), `TrainConfig`, `train_amlnet`,
  `load_model(run_dir)`, `export_weights(run_dir, out_dir)` (weights only, for shipping),
  `shipped_checkpoint(name)` (the weights in the package: "heat_nocart_cpu" + "zoom_fit_cpu", the
  default IML pair, `iml.DEFAULT_AMLNET`; "heat_chroma_cpu" + "zoom_fit_cpu"; "heat_fit_cpu" + "zoom_fit_cpu"; "amlnet_cpu" + "zoom_cpu";
  "heat_cpu" + "zoom_luma_cpu"; "heat_fit167_cpu" + "zoom_fit167_cpu", made with
  "refiner_fit167_cpu" by one from-scratch `fit` run, with "refiner_fit180_cpu" by its 180-minute
  budget; "refiner_paint_cpu" + the fine ensemble "refiner_fine_paint_cpu" and "refiner_fine_native_cpu",
  the default IR stage, `refine.load_stage`, and the refiners they were trained from, "refiner_cpu",
  "refiner_fine_more_cpu", "refiner_fine_long_cpu" and "refiner_fine_cpu");
  `ToyRectangles` is a toy source for tests only;

The zoom-in stage, a small AMLNet (config task "zoom") on a crop around AMLNet's estimate, has
its own package beside this one: `rhaml_jax.zoom` (its crop, targets, decoding, training data).
"""

from rhaml_jax.amlnet.acn import acn, acn_reference
from rhaml_jax.amlnet.checkpoint import export_weights, load_model, shipped_checkpoint
from rhaml_jax.amlnet.config import (AMLNetConfig, FrontNetConfig, config_from_dict, config_names, config_to_dict,
                                     get_config)
from rhaml_jax.amlnet.count import count_macs, count_params
from rhaml_jax.amlnet.data import Batch, BatchSource, ToyRectangles
from rhaml_jax.amlnet.describe import describe
from rhaml_jax.amlnet.functional import Net, build, check_images
from rhaml_jax.amlnet.loss import amlnet_loss, decode
from rhaml_jax.amlnet.trainer import TrainConfig, train_amlnet

__all__ = [
    "AMLNetConfig", "FrontNetConfig", "get_config", "config_names", "config_to_dict", "config_from_dict",
    "Net", "build", "check_images", "acn", "acn_reference", "decode", "amlnet_loss",
    "count_params", "count_macs", "describe", "Batch", "BatchSource", "ToyRectangles",
    "TrainConfig", "train_amlnet", "load_model", "export_weights", "shipped_checkpoint",
]
