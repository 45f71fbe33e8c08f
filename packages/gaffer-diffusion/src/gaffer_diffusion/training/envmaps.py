"""The environment maps of a render's lightings, as training reads them: found on disk, augmented as
rendered, resized solid-angle-exactly to `[h, 2h]` and clamped to `data.max_radiance`, kept in a
per-process LRU (`EnvmapCache`)."""

import logging
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gaffer_data.dataset import EnvmapRef

# the dataset's warnings keep the logger name they had before the module was split
logger = logging.getLogger("gaffer_diffusion.training.dataset")

_ENVMAP_SUFFIXES = (".exr", ".hdr")


class EnvmapCache:
    """Per-process LRU of augmented, resized environment maps (`[h, 2h, 3]` float32)."""

    def __init__(self, capacity: int, height: int, max_radiance: float, dirs: Sequence[Path]):
        self.capacity = max(capacity, 1)
        self.height = height
        self.max_radiance = max_radiance
        self.dirs = tuple(dirs)
        self._items: OrderedDict[tuple[str, bool, int, int], np.ndarray] = OrderedDict()
        # decoded source maps: one file serves all its flips and yaw steps
        self.source_capacity = 8
        self._sources: OrderedDict[Path, Any] = OrderedDict()

    def resolve(self, ref: EnvmapRef, dataset_root: Path) -> Path:
        """The file of `ref`: its recorded source (as is, or under the dataset), else `dirs`.

        Raises:
            FileNotFoundError: in none of those places.
        """
        candidates = [Path(ref.source), dataset_root / ref.source, dataset_root.parent / ref.source]
        for d in self.dirs:
            candidates += [d / f"{ref.name}{s}" for s in _ENVMAP_SUFFIXES]
            candidates.append(d / Path(ref.source).name)
        for c in candidates:
            if c.is_file():
                return c
        raise FileNotFoundError(
            f"environment map {ref.name!r} (recorded source {ref.source}) not found; add its folder to "
            "`data.envmap_dirs`"
        )

    def get(self, ref: EnvmapRef, dataset_root: Path) -> np.ndarray:
        """`[height, 2 height, 3]` float32 linear radiance of `ref`, augmented as rendered (read-only)."""
        key = (ref.source, ref.flip, ref.yaw_step, ref.num_steps)
        hit = self._items.get(key)
        if hit is not None:
            self._items.move_to_end(key)
            return hit
        from gaffer_envmap.augment import AugmentSpec
        from gaffer_envmap.io import read_envmap
        from gaffer_envmap.resample import resize_conservative

        path = self.resolve(ref, dataset_root)
        env = self._sources.get(path)
        if env is None:
            env = read_envmap(path, sanitize="clamp")
            self._sources[path] = env
            if len(self._sources) > self.source_capacity:
                self._sources.popitem(last=False)
        else:
            self._sources.move_to_end(path)
        # the augmentation the renderer applied, at the source resolution (exact pixel rolls)
        env = AugmentSpec(flip=ref.flip, yaw_step=ref.yaw_step, num_steps=ref.num_steps).apply(env)
        if env.height != self.height:
            env = resize_conservative(env, self.height)
        rad = np.asarray(env.radiance_linear, dtype=np.float32)
        if float(rad.max(initial=0.0)) > self.max_radiance:
            # an extreme sun would overflow float32 in the HDR normaliser log1p(10 E)
            logger.warning(
                "environment map %s has radiance up to %.3g; clamped to `data.max_radiance` %.3g",
                ref.source,
                float(rad.max()),
                self.max_radiance,
            )
            rad = np.minimum(rad, self.max_radiance)
        rad = np.ascontiguousarray(rad)
        rad.flags.writeable = False
        self._items[key] = rad
        if len(self._items) > self.capacity:
            self._items.popitem(last=False)
        return rad
