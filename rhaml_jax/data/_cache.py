"""A byte-budgeted in-memory cache of decoded images, shared by the training sources."""

from __future__ import annotations

from typing import Callable, Hashable

import numpy as np


class ImageCache:
    """Arrays by key, kept while their total size stays within `max_bytes` (0 keeps none).

    Training sources read the same images every epoch; decoding (and resampling) a PNG costs
    a third of a `cpu` training step's time per image. The first images to arrive stay;
    later ones that would overflow the budget are returned but not kept (no eviction: an epoch
    visits every image once, so any replacement policy would keep the same number)."""

    def __init__(self, max_bytes: int):
        self.max_bytes, self.nbytes = max_bytes, 0
        self._items: dict[Hashable, np.ndarray] = {}

    def get(self, key: Hashable, load: Callable[[], np.ndarray]) -> np.ndarray:
        img = self._items.get(key)
        if img is None:
            img = load()
            if self.nbytes + img.nbytes <= self.max_bytes:
                self._items[key] = img
                self.nbytes += img.nbytes
        return img

    def __len__(self) -> int:
        return len(self._items)
