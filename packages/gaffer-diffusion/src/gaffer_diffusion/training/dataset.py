"""Training samples from gaffer-data renders (paper §3.1, official implementation §3).

One sample = one object view: an input image under one lighting (with probability `area_light_prob`
the area-light render, otherwise an environment-map render of the same view) and
`targets_per_sample` renders of the same view under OTHER environment-map draws, with those draws'
environment maps (augmented exactly as rendered, resized to `[envmap_height, 2 envmap_height]`) and the
view's Blender world-to-camera matrix. The lighting conditioning (rotation into the camera frame, LDR/HDR
split) is NOT computed here: `encode_batch_lighting` does it for the whole batch on the training device,
with no PNG round trip.

Images are the renders' 8-bit sRGB PNGs (straight alpha), composited on white and resized (bilinear,
antialiased) to the model resolution, as the authors preprocess them.

Converted authors' splits (`gaffer-data convert-authors`, schema "gaffer.authors_dataset") are read too,
mixed freely with renders: their images are sampled the same way, but their lighting comes as the
authors' pre-encoded camera-frame LDR/HDR PNGs, which are used as they are (read and resized to the
model resolution with `gaffer_diffusion.evaluation`'s reader, PIL bilinear; no environment map, no
re-encoding). Such items carry `encoded_ldr` / `encoded_hdr` instead of `envmaps`; `batch_lighting`
fills a batch's lighting from both kinds.

Determinism: an item depends only on `(seed, key)`; `KeySampler` yields keys
`epoch * len(dataset) + index` from a seeded permutation per epoch and can start at any position, so a
resumed run sees exactly the samples an uninterrupted run would have seen.

Robustness: an object whose manifest or cameras cannot be read is left out at construction; an item
whose files are missing or corrupt is replaced by another one (drawn from the same seeded generator),
and every such event is counted in the batch (`TrainBatch.skipped`) and logged by the training loop.

This module holds the Dataset class, `RelightTrainDataset` (which views of which objects, and the
retries); the rest lives one thing per module and is re-exported here:

- `gaffer_diffusion.training.batch`: the records, `TrainItem`, `TrainBatch`, `collate_items`;
- `gaffer_diffusion.training.objects`: `dataset_object_ids`, `split_object_ids`,
  `check_lighting_compat`;
- `gaffer_diffusion.training.sampler`: `KeySampler`;
- `gaffer_diffusion.training.reading`: one item from disk (`load_image_on_white`, `read_render_item`,
  `read_authors_item`), with `gaffer_diffusion.training.envmaps.EnvmapCache` for environment maps;
- `gaffer_diffusion.training.lighting`: `encode_batch_lighting`, `batch_lighting`, `batch_lighting_of`.
"""

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from gaffer_data import GafferDataError, read_object
from gaffer_data.dataset import (
    AuthorsObject,
    AuthorsView,
    RenderedObject,
    ViewRecord,
    dataset_kind,
    read_authors_object,
)
from gaffer_data.dataset import DatasetKind as DatasetKind  # re-exported: it moved to gaffer-data
from gaffer_diffusion.preprocess import load_rgba_on_white as load_rgba_on_white
from gaffer_diffusion.training.batch import TrainBatch as TrainBatch
from gaffer_diffusion.training.batch import TrainItem
from gaffer_diffusion.training.batch import collate_items as collate_items
from gaffer_diffusion.training.config import DataConfig
from gaffer_diffusion.training.envmaps import EnvmapCache
from gaffer_diffusion.training.errors import DataError
from gaffer_diffusion.training.lighting import batch_lighting as batch_lighting
from gaffer_diffusion.training.lighting import batch_lighting_of as batch_lighting_of
from gaffer_diffusion.training.lighting import encode_batch_lighting as encode_batch_lighting
from gaffer_diffusion.training.objects import check_lighting_compat, dataset_object_ids
from gaffer_diffusion.training.objects import split_object_ids as split_object_ids
from gaffer_diffusion.training.reading import load_image_on_white as load_image_on_white
from gaffer_diffusion.training.reading import read_authors_item, read_render_item
from gaffer_diffusion.training.sampler import KeySampler as KeySampler

logger = logging.getLogger(__name__)


@dataclass(frozen=True, kw_only=True)
class _ViewEntry:
    object_index: int
    view: ViewRecord | AuthorsView
    w2c_blender: np.ndarray


if TYPE_CHECKING:
    _RootsArg = Sequence[str | Path]
else:  # a single path also reaches `RelightTrainDataset`, which refuses it with a DataError naming
    _RootsArg = Sequence[str | Path] | Path  # the fix (a str is a sequence of str already)


class RelightTrainDataset(torch.utils.data.Dataset[TrainItem]):
    """Samples of one or more datasets, indexed by (object, view).

    Args:
        roots: `gaffer-data render` output folders and/or converted authors' splits (`gaffer-data
            convert-authors --out`), in any mix; each folder's kind is read from its `dataset.json`.
        config: sampling settings (`targets_per_sample`, `area_light_prob`, envmap size, ...).
        resolution: model image size (images and the authors' encoded maps are resized to it).
        seed: item seed; item `key` is drawn from `np.random.default_rng([seed, key])`.
        include: only these object ids (None: all).
        exclude: never these object ids.

    Raises:
        DataError: a folder is not a dataset, no usable view in the given folders, or renders mixed
            with authors' splits under `data.lighting_compat="default"`.

    Example:
        >>> ds = RelightTrainDataset(["renders/"], DataConfig(root=Path("renders/")), 64)  # doctest: +SKIP
        >>> item = ds[0]  # doctest: +SKIP
        >>> item.target_images.shape  # doctest: +SKIP
        torch.Size([2, 3, 64, 64])
    """

    def __init__(
        self,
        roots: _RootsArg,
        config: DataConfig,
        resolution: int,
        *,
        seed: int = 0,
        include: Sequence[str] | None = None,
        exclude: Sequence[str] = (),
    ) -> None:
        if isinstance(roots, str | Path):
            raise DataError(
                f"`roots` is the single path {str(roots)!r}; pass a list of dataset folders "
                f"([{str(roots)!r}])."
            )
        self.config = config
        self.resolution = int(resolution)
        self.seed = int(seed)
        self.objects: list[RenderedObject | AuthorsObject] = []
        self.entries: list[_ViewEntry] = []
        self.skipped_objects: list[str] = []
        self.skipped_views = 0
        wanted = None if include is None else set(include)
        excluded = set(exclude)
        t = config.targets_per_sample
        check_lighting_compat(roots, config.lighting_compat)
        for root in roots:
            authors = dataset_kind(root) == "authors"
            ids = dataset_object_ids(root)
            for oid in ids:
                if (wanted is not None and oid not in wanted) or oid in excluded:
                    continue
                try:
                    obj: RenderedObject | AuthorsObject
                    if authors:
                        obj = read_authors_object(Path(root) / "objects" / oid)
                    else:
                        obj = read_object(Path(root) / "objects" / oid)
                    poses = obj.poses()
                except (GafferDataError, OSError, ValueError) as exc:
                    self.skipped_objects.append(f"{oid}: {exc}")
                    continue
                oi = len(self.objects)
                self.objects.append(obj)
                for view in obj.views:
                    n_lit = len(view.lit)
                    has_area = (
                        view.area_png is not None
                        if isinstance(view, AuthorsView)
                        else view.area is not None
                    )
                    if n_lit >= t + 1 or (has_area and n_lit >= t):
                        row = view.row if isinstance(view, AuthorsView) else view.index
                        w2c = np.asarray(poses.w2c_blender[row], dtype=np.float32)
                        self.entries.append(_ViewEntry(object_index=oi, view=view, w2c_blender=w2c))
                    else:
                        self.skipped_views += 1
        if self.skipped_objects:
            logger.warning(
                "skipped %d unreadable object(s): %s",
                len(self.skipped_objects),
                "; ".join(self.skipped_objects[:5]),
            )
        if self.skipped_views:
            logger.warning(
                "skipped %d view(s) with fewer than %d environment-map renders (+ an area render)",
                self.skipped_views,
                t + 1,
            )
        if not self.entries:
            raise DataError(
                f"No usable view in {[str(r) for r in roots]}: need complete objects (with "
                f"manifest.json) whose views have >= {t + 1} environment-map renders, or {t} plus an "
                "area-light render (a converted authors' split: images per view, or 'random_lighting' "
                "+ images). Render with `gaffer-data render --lightings N` (N > "
                "`data.targets_per_sample`) or lower `data.targets_per_sample`."
            )
        self._cache = EnvmapCache(
            config.envmap_cache_size, config.envmap_height, config.max_radiance, config.envmap_dirs
        )

    def __len__(self) -> int:
        return len(self.entries)

    @property
    def object_ids(self) -> tuple[str, ...]:
        """Ids of the objects that contribute views."""
        return tuple(o.object_id for o in self.objects)

    def __getitem__(self, key: int) -> TrainItem:
        """The item for `key` (any non-negative int; `key % len(self)` picks the view).

        Raises:
            DataError: `data.max_load_retries` replacements in a row were unreadable too.
        """
        rng = np.random.default_rng([self.seed, int(key)])
        index = int(key) % len(self.entries)
        failed: list[str] = []
        for _ in range(self.config.max_load_retries + 1):
            try:
                item = self._load(self.entries[index], rng)
            except (OSError, ValueError, GafferDataError) as exc:
                failed.append(f"{self._describe(index)}: {exc}")
                logger.warning("skipping unreadable sample %s", failed[-1])
                index = int(rng.integers(len(self.entries)))
                continue
            if failed:
                return dataclasses.replace(item, skipped=len(failed), skipped_files=tuple(failed))
            return item
        raise DataError(
            f"{len(failed)} samples in a row could not be read (last: {failed[-1]}). Check the "
            "dataset with `gaffer-data info ROOT --verify` and re-render (or re-convert) the broken "
            "objects."
        )

    def _describe(self, index: int) -> str:
        e = self.entries[index]
        return f"{self.objects[e.object_index].object_id}/view {e.view.index}"

    def _load(self, entry: _ViewEntry, rng: np.random.Generator) -> TrainItem:
        obj = self.objects[entry.object_index]
        if isinstance(obj, AuthorsObject) and isinstance(entry.view, AuthorsView):
            return read_authors_item(
                obj,
                entry.view,
                entry.w2c_blender,
                rng,
                config=self.config,
                resolution=self.resolution,
            )
        if not (isinstance(obj, RenderedObject) and isinstance(entry.view, ViewRecord)):
            raise DataError(f"internal: view entry of {obj.object_id!r} mixes dataset kinds")
        return read_render_item(
            obj,
            entry.view,
            entry.w2c_blender,
            rng,
            config=self.config,
            resolution=self.resolution,
            envmaps=self._cache,
        )
