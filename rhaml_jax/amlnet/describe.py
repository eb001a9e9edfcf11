"""`describe(config, bench, batch)` (a config name or a loaded network's config): the JSON behind
`python -m rhaml_jax.info --config`."""

from __future__ import annotations

import statistics

from rhaml_jax.amlnet.config import ModelConfig, get_config
from rhaml_jax.amlnet.count import count_macs, count_params
from rhaml_jax.amlnet.functional import build
from rhaml_jax.errors import RhamlError

__all__ = ["describe"]


def describe(config_name: str | ModelConfig, bench: bool = False, batch: int = 8, runs: int = 3) -> dict:
    """{"config", "params", "macs", "input_shape"} (+ measured "inference_images_per_s",
    "train_images_per_s" with `bench`).  params and MACs are counted from the model (see
    count.py; MACs per image at the config's input size); input_shape is one image, (H, W, 3)
    float32 in [0, 1].  The training step is the trainer's: gradient jit + AdamW jit."""
    cfg = get_config(config_name) if isinstance(config_name, str) else config_name  # a name, or a loaded network's config
    if batch < 1:
        raise RhamlError(f"--batch {batch}: must be positive")
    net = build(cfg, abstract=True)
    h, w = cfg.input_hw
    out = {"config": cfg.name, "params": count_params(cfg, net=net), "macs": count_macs(cfg, net=net),
           "input_shape": [h, w, 3]}
    if bench:
        from rhaml_jax.amlnet.bench import ModelBench

        b = ModelBench(cfg, batch)
        out["batch"] = batch
        out["inference_images_per_s"] = batch / statistics.median(b.inference_s(runs))
        out["train_images_per_s"] = batch / statistics.median(b.train_s(runs))
        out["compile_s"] = b.compile_s
    return out
