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
"""

import dataclasses
import hashlib
import logging
from collections import OrderedDict
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

from gaffer_data import GafferDataError, open_authors_dataset, open_dataset, read_object
from gaffer_data.dataset import (
    AuthorsObject,
    AuthorsView,
    EnvmapRef,
    RenderedObject,
    ViewRecord,
    dataset_kind,
    read_authors_object,
)
from gaffer_data.dataset import DatasetKind as DatasetKind  # re-exported: it moved to gaffer-data
from gaffer_diffusion.errors import ConfigError
from gaffer_diffusion.preprocess import load_rgba_on_white, object_square, read_alpha
from gaffer_diffusion.training.config import DataConfig, LightingCompat
from gaffer_diffusion.training.errors import DataError
from gaffer_diffusion.training.exposure import exposure_gains, reexpose_on_white

logger = logging.getLogger(__name__)

_ENVMAP_SUFFIXES = (".exr", ".hdr")


@dataclass(frozen=True, kw_only=True)
class TrainItem:
    """One training sample (channels-first images in [0, 1], sRGB, on white).

    The target lighting is given one of two ways: `envmaps` (a gaffer-data render; encoded later, batched,
    on the training device) or `encoded_ldr` + `encoded_hdr` (a converted authors' split: their
    camera-frame maps, used as they are). Exactly one of the two is set.

    Attributes:
        input_image: `[3, H, W]` the input view.
        target_images: `[T, 3, H, W]` the same view under the T target lightings.
        envmaps: `[T, He, We, 3]` linear radiance of the target lightings (Blender world frame), or None
            for an item with pre-encoded lighting.
        w2c_blender: `[3, 4]` world-to-camera matrix of the view (Blender camera axes).
        input_is_area: the input is the area-light render.
        object_id: the object.
        view_index: the view.
        skipped: unreadable items replaced before this one was found.
        skipped_files: the files that failed (one per replaced item).
        encoded_ldr: `[T, 3, H, W]` the authors' camera-frame LDR maps of the targets in [0, 1], at the
            image resolution, or None (the item has `envmaps`).
        encoded_hdr: `[T, 3, H, W]` the matching HDR maps, or None.
        input_alpha: `[1, H, W]` the input view's object mask (its alpha), or None when unknown;
            validation keeps the input's background with it (`RelightingConditions.mask`).

    Raises:
        DataError: both or neither lighting forms are given, or their shapes disagree.
    """

    input_image: Float[Tensor, "3 H W"]
    target_images: Float[Tensor, "T 3 H W"]
    envmaps: Float[Tensor, "T He We 3"] | None
    w2c_blender: Float[Tensor, "3 4"]
    input_is_area: bool
    object_id: str
    view_index: int
    skipped: int = 0
    skipped_files: tuple[str, ...] = ()
    encoded_ldr: Float[Tensor, "T 3 H W"] | None = None
    encoded_hdr: Float[Tensor, "T 3 H W"] | None = None
    input_alpha: Float[Tensor, "1 H W"] | None = None

    def __post_init__(self) -> None:
        encoded = (self.encoded_ldr is not None, self.encoded_hdr is not None)
        if encoded[0] != encoded[1] or (self.envmaps is None) != encoded[0]:
            raise DataError(
                f"`TrainItem` of {self.object_id!r} view {self.view_index}: give either `envmaps` or "
                "both `encoded_ldr` and `encoded_hdr`, not a mix."
            )
        t = self.target_images.shape[0]
        if self.envmaps is not None and self.envmaps.shape[0] != t:
            raise DataError(
                f"`TrainItem.envmaps` has {self.envmaps.shape[0]} maps for {t} target images."
            )
        for name in ("encoded_ldr", "encoded_hdr"):
            m = getattr(self, name)
            if m is not None and tuple(m.shape) != tuple(self.target_images.shape):
                raise DataError(
                    f"`TrainItem.{name}` has shape {tuple(m.shape)}; expected the target images' "
                    f"{tuple(self.target_images.shape)} (resize the maps to the image resolution)."
                )

    @property
    def lighting_encoded(self) -> bool:
        """The lighting is pre-encoded (`encoded_ldr` / `encoded_hdr`), not `envmaps`."""
        return self.envmaps is None


@dataclass(frozen=True, kw_only=True)
class TrainBatch:
    """A collated batch of `TrainItem`s.

    Items of a render carry environment maps, items of a converted authors' split pre-encoded maps;
    `lighting_encoded` says which item is which, and `envmaps` / `encoded_*` hold only the rows of their
    kind, in batch order (`batch_lighting` puts them back together). Without authors' items `envmaps`
    holds all B items and `encoded_*` are empty.

    Attributes:
        input_images: `[B, 3, H, W]`.
        target_images: `[B, T, 3, H, W]`.
        envmaps: `[Be, T, He, We, 3]` linear radiance of the Be items with `lighting_encoded` False.
        w2c_blender: `[B, 3, 4]`.
        input_is_area: `[B]` bool.
        skipped: unreadable items replaced while loading this batch.
        skipped_files: their files.
        lighting_encoded: `[B]` bool, True for items with pre-encoded lighting (None: all False).
        encoded_ldr: `[Ba, T, 3, H, W]` the pre-encoded LDR maps of the Ba other items (None: Ba = 0).
        encoded_hdr: `[Ba, T, 3, H, W]` their HDR maps (None: Ba = 0).
        input_alphas: `[B, 1, H, W]` the inputs' object masks, or None when an item has none.
    """

    input_images: Float[Tensor, "B 3 H W"]
    target_images: Float[Tensor, "B T 3 H W"]
    envmaps: Float[Tensor, "Be T He We 3"]
    w2c_blender: Float[Tensor, "B 3 4"]
    input_is_area: Tensor
    skipped: int = 0
    skipped_files: tuple[str, ...] = ()
    lighting_encoded: Tensor | None = None
    encoded_ldr: Float[Tensor, "Ba T 3 H W"] | None = None
    encoded_hdr: Float[Tensor, "Ba T 3 H W"] | None = None
    input_alphas: Float[Tensor, "B 1 H W"] | None = None

    @property
    def batch_size(self) -> int:
        """B."""
        return int(self.input_images.shape[0])

    @property
    def targets_per_sample(self) -> int:
        """T."""
        return int(self.target_images.shape[1])

    def pin_memory(self) -> "TrainBatch":
        """Page-locked copies (DataLoader `pin_memory=True` calls this)."""
        return TrainBatch(
            input_images=self.input_images.pin_memory(),
            target_images=self.target_images.pin_memory(),
            envmaps=self.envmaps.pin_memory(),
            w2c_blender=self.w2c_blender.pin_memory(),
            input_is_area=self.input_is_area,
            skipped=self.skipped,
            skipped_files=self.skipped_files,
            lighting_encoded=self.lighting_encoded,
            encoded_ldr=None if self.encoded_ldr is None else self.encoded_ldr.pin_memory(),
            encoded_hdr=None if self.encoded_hdr is None else self.encoded_hdr.pin_memory(),
            input_alphas=None if self.input_alphas is None else self.input_alphas.pin_memory(),
        )


def collate_items(items: Sequence[TrainItem]) -> TrainBatch:
    """Stack `TrainItem`s into a `TrainBatch` (the DataLoader's `collate_fn`).

    Raises:
        DataError: the items disagree on the number of targets or the image / map sizes.
    """
    env = [i.envmaps for i in items if i.envmaps is not None]
    ldr = [i.encoded_ldr for i in items if i.encoded_ldr is not None]
    hdr = [i.encoded_hdr for i in items if i.encoded_hdr is not None]
    t = items[0].target_images.shape[0] if items else 0
    try:
        return TrainBatch(
            input_images=torch.stack([i.input_image for i in items]),
            target_images=torch.stack([i.target_images for i in items]),
            envmaps=torch.stack(env) if env else torch.zeros(0, t, 0, 0, 3),
            w2c_blender=torch.stack([i.w2c_blender for i in items]),
            input_is_area=torch.tensor([i.input_is_area for i in items]),
            skipped=sum(i.skipped for i in items),
            skipped_files=tuple(f for i in items for f in i.skipped_files),
            lighting_encoded=torch.tensor([i.lighting_encoded for i in items]) if ldr else None,
            encoded_ldr=torch.stack(ldr) if ldr else None,
            encoded_hdr=torch.stack(hdr) if hdr else None,
            input_alphas=torch.stack([i.input_alpha for i in items])  # type: ignore[misc]
            if items and all(i.input_alpha is not None for i in items)
            else None,
        )
    except RuntimeError as exc:  # torch.stack on mismatched shapes
        raise DataError(
            f"cannot batch these items: {exc}. Every dataset of a run must be read at the same "
            "`resolution`, `data.targets_per_sample` and `data.envmap_height`."
        ) from exc


def split_object_ids(
    object_ids: Sequence[str], num_val: int, *, salt: str = "gaffer-val"
) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Deterministic (train, val) split: the `num_val` ids with the smallest sha256(salt + id).

    Independent of the order and of ids added later (an object never moves from train to val).

    Raises:
        ConfigError: when `num_val` (`data.val_objects`) is not below the number of objects: holding
            them all out would leave nothing to train on (it used to be cut silently to
            `len(object_ids) - 1`, so `val_objects: 50` on 12 objects trained on 1, issue 17).
    """
    if num_val > 0 and num_val >= len(object_ids):
        n = len(object_ids)
        fix = (
            f"pass `data.val_objects` of at most {n - 1} (e.g. {max(1, n // 10)})"
            if n > 1
            else "render more objects (at least 2)"
        )
        raise ConfigError(
            f"`data.val_objects` is {num_val}, but the dataset (`data.root`) holds {n} object(s): "
            f"holding out {num_val} would leave none to train on. {fix.capitalize()}, set it to 0 "
            "(no validation), or hold out a separate `data.val_root`."
        )
    ranked = sorted(object_ids, key=lambda i: hashlib.sha256(f"{salt}:{i}".encode()).hexdigest())
    val = set(ranked[:num_val])
    return (
        tuple(i for i in sorted(object_ids) if i not in val),
        tuple(i for i in sorted(object_ids) if i in val),
    )


def load_image_on_white(
    path: Path,
    size: int,
    alpha_path: Path | None = None,
    box: tuple[int, int, int] | None = None,
) -> Float[Tensor, "3 S S"]:
    """An sRGB PNG with straight alpha composited on white, resized to `size` (bilinear, antialiased).

    Args:
        path: RGBA (or RGB) 8-bit image.
        size: output side length.
        alpha_path: a separate 8-bit mask used when the image has no alpha channel.
        box: square crop `(top, left, side)` (`gaffer_diffusion.preprocess.object_square`) or None.

    Returns:
        `[3, size, size]` float32 in [0, 1].

    Raises:
        OSError: unreadable or truncated file (PIL's errors).
        ValueError: unusable image data.
    """
    return load_rgba_on_white(path, size, alpha_path, box)[0]


class _EnvmapCache:
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


def dataset_object_ids(root: str | Path) -> tuple[str, ...]:
    """The complete objects of a render folder or of a converted authors' split, sorted.

    Raises:
        DataError: `root` is not a dataset folder (naming the argument and the fix).
    """
    try:
        if dataset_kind(root) == "authors":
            return tuple(open_authors_dataset(root).object_ids)
        return tuple(open_dataset(root).object_ids)
    except (GafferDataError, OSError, ValueError) as exc:
        raise DataError(
            f"`data.root` / `data.val_root` {str(root)!r} is not a readable dataset ({exc}). Pass a "
            "`gaffer-data render` output folder or the `--out` folder of `gaffer-data "
            "convert-authors`."
        ) from exc


def check_lighting_compat(roots: Sequence[str | Path], compat: LightingCompat) -> None:
    """Refuse a run that would mix the authors' encoded maps with another lighting encoding.

    The authors' maps (converted splits) are the "neural-gaffer" encoding; environment maps of render
    folders are encoded with `compat`. Both in one run (training or validation) need
    `compat == "neural-gaffer"`, or the model sees two different conditionings for the same light.

    Raises:
        DataError: renders and authors' splits together with `compat="default"`.
    """
    kinds = {str(r): dataset_kind(r) for r in roots}
    authors = [r for r, k in kinds.items() if k == "authors"]
    renders = [r for r, k in kinds.items() if k == "render"]
    if authors and renders and compat != "neural-gaffer":
        raise DataError(
            f"The converted authors' split(s) {authors} come with the authors' 'neural-gaffer' "
            f"lighting encoding, but the render folder(s) {renders} would be encoded with "
            f"`data.lighting_compat` = {compat!r}. Set `data.lighting_compat` to 'neural-gaffer' to "
            "mix them, or train and validate on one kind of dataset."
        )


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
        self._cache = _EnvmapCache(
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
            return self._load_authors(obj, entry, entry.view, rng)
        if not (isinstance(obj, RenderedObject) and isinstance(entry.view, ViewRecord)):
            raise DataError(f"internal: view entry of {obj.object_id!r} mixes dataset kinds")
        view = entry.view
        t = self.config.targets_per_sample
        lit = view.lit
        # Neural Gaffer §3.1: 10% of inputs are the area-light render, else another envmap render
        draw = float(rng.random())
        use_area = view.area is not None and (
            draw < self.config.area_light_prob or len(lit) < t + 1
        )
        order = rng.permutation(len(lit))
        targets = [lit[i] for i in order[:t]]
        alpha = None if view.alpha is None else obj.path(view.alpha)
        size = self.resolution
        input_png = obj.path(
            view.area.png if use_area and view.area is not None else lit[int(order[t])].png
        )
        box = None
        if self.config.object_fraction is not None:
            # one square per view (input and targets alike): the object centred, filling the frame
            box = object_square(read_alpha(alpha or input_png), self.config.object_fraction)
        input_image, input_alpha = load_rgba_on_white(input_png, size, alpha, box)
        target_images = torch.stack(
            [load_image_on_white(obj.path(li.png), size, alpha, box) for li in targets]
        )
        envmaps = torch.stack(
            [
                torch.from_numpy(self._cache.get(li.envmap, obj.root.parent.parent).copy())
                for li in targets
            ]
        )
        a, b = self.config.target_exposure_stops, self.config.target_tint_stops
        if a > 0 or b > 0:
            # drawn after every other draw, so the rest of the item is as without the augmentation
            for j in range(t):
                stops = float(rng.uniform(-a, a)) + rng.uniform(-b, b, size=3)
                gains = exposure_gains(torch.from_numpy(stops), target_images[j], input_alpha)
                target_images[j] = reexpose_on_white(target_images[j], input_alpha, gains)
                envmaps[j] = envmaps[j] * gains.to(envmaps.dtype)
        return TrainItem(
            input_image=input_image,
            target_images=target_images,
            envmaps=envmaps,
            w2c_blender=torch.from_numpy(entry.w2c_blender.copy()),
            input_is_area=bool(use_area),
            object_id=obj.object_id,
            view_index=view.index,
            input_alpha=input_alpha,
        )

    def _load_authors(
        self,
        obj: AuthorsObject,
        entry: _ViewEntry,
        view: AuthorsView,
        rng: np.random.Generator,
    ) -> TrainItem:
        """An item of a converted authors' split: the same draws as `_load`, their encoded maps."""
        # evaluation's reader of the authors' maps: RGB, PIL bilinear when resized, [1, 3, S, S]
        from gaffer_diffusion.evaluation import read_lighting_map

        t = self.config.targets_per_sample
        lit = view.lit
        draw = float(rng.random())
        use_area = view.area_png is not None and (
            draw < self.config.area_light_prob or len(lit) < t + 1
        )
        order = rng.permutation(len(lit))
        targets = [lit[i] for i in order[:t]]
        size = self.resolution
        if use_area and view.area_png is not None:
            input_image = load_image_on_white(obj.path(view.area_png), size)
        else:
            input_image = load_image_on_white(obj.path(lit[int(order[t])].png), size)
        target_images = torch.stack([load_image_on_white(obj.path(li.png), size) for li in targets])
        ldr = torch.cat([read_lighting_map(obj.path(li.envmap_ldr), size) for li in targets])
        hdr = torch.cat([read_lighting_map(obj.path(li.envmap_hdr), size) for li in targets])
        return TrainItem(
            input_image=input_image,
            target_images=target_images,
            envmaps=None,
            encoded_ldr=ldr,
            encoded_hdr=hdr,
            w2c_blender=torch.from_numpy(entry.w2c_blender.copy()),
            input_is_area=bool(use_area),
            object_id=obj.object_id,
            view_index=view.index,
        )


class KeySampler(torch.utils.data.Sampler[int]):
    """An endless, resumable stream of item keys, sharded over processes.

    Position p (counted over all processes) maps to `key = epoch * n + perm_epoch[p % n]` with
    `epoch = p // n` and a permutation seeded by `(seed, epoch)`. Process `rank` of `world_size` takes
    positions `start + rank, start + rank + world_size, ...`.

    Args:
        num_items: n, the dataset length.
        seed: permutation seed.
        start: global position to start from (samples already consumed, for resuming).
        rank: this process's index.
        world_size: number of processes.
        shuffle: permute each epoch (False: identity order).
    """

    def __init__(
        self,
        num_items: int,
        *,
        seed: int = 0,
        start: int = 0,
        rank: int = 0,
        world_size: int = 1,
        shuffle: bool = True,
    ) -> None:
        if num_items < 1 or not 0 <= rank < world_size or start < 0:
            raise DataError(
                f"`KeySampler` got num_items={num_items}, rank={rank}, world_size={world_size}, "
                f"start={start}; need num_items >= 1, 0 <= rank < world_size, start >= 0."
            )
        self.num_items = num_items
        self.seed = seed
        self.start = start
        self.rank = rank
        self.world_size = world_size
        self.shuffle = shuffle

    def _perm(self, epoch: int) -> Tensor:
        if not self.shuffle:
            return torch.arange(self.num_items)
        g = torch.Generator().manual_seed(self.seed * 1_000_003 + epoch)
        return torch.randperm(self.num_items, generator=g)

    def __iter__(self) -> Iterator[int]:
        p = self.start + self.rank
        epoch, perm = -1, torch.arange(0)
        while True:
            e = p // self.num_items
            if e != epoch:
                epoch, perm = e, self._perm(e)
            yield int(e * self.num_items + int(perm[p % self.num_items]))
            p += self.world_size


def encode_batch_lighting(
    envmaps: Float[Tensor, "N He We 3"],
    w2c_blender: Float[Tensor, "N 3 4"],
    *,
    size: int,
    compat: LightingCompat,
    device: torch.device | str | None = None,
) -> tuple[Float[Tensor, "N 3 S S"], Float[Tensor, "N 3 S S"]]:
    """Camera-frame LDR and HDR maps of N (map, pose) pairs in one batched gaffer-envmap call.

    Neural Gaffer §3.2: each map is rotated into its view's camera frame and split into E_L / E_H.

    Returns:
        `(ldr, hdr)`, each `[N, 3, size, size]` float32 in [0, 1] on `device`.
    """
    from gaffer_diffusion.conditioning import LIGHTING_FILTER, LIGHTING_SUPERSAMPLE
    from gaffer_envmap.encode import encode_lighting

    enc = encode_lighting(
        envmaps.to(device=device, dtype=torch.float32),
        w2c_blender.detach().double().cpu(),
        size=size,
        compat=compat,
        filter=LIGHTING_FILTER,  # what the model is sampled with (conditioning.LIGHTING_FILTER)
        supersample=LIGHTING_SUPERSAMPLE,
        device=device,
    )
    return enc.ldr.to(device=device, dtype=torch.float32), enc.hdr.to(
        device=device, dtype=torch.float32
    )


def batch_lighting(
    envmaps: Float[Tensor, "Ne He We 3"],
    w2c_blender: Float[Tensor, "N 3 4"],
    *,
    encoded: Tensor | None = None,
    encoded_ldr: Float[Tensor, "Na 3 S S"] | None = None,
    encoded_hdr: Float[Tensor, "Na 3 S S"] | None = None,
    size: int,
    compat: LightingCompat,
    device: torch.device | str | None = None,
) -> tuple[Float[Tensor, "N 3 S S"], Float[Tensor, "N 3 S S"]]:
    """Camera-frame LDR and HDR maps of N lightings given as environment maps and/or encoded maps.

    Rows where `encoded` is False come from `envmaps` (in order; rotated into the row's camera frame
    and encoded by `encode_batch_lighting`, one call), rows where it is True from `encoded_ldr` /
    `encoded_hdr` (in order; the authors' maps, used as they are).

    Args:
        envmaps: `[Ne, He, We, 3]` the environment maps of the rows with `encoded` False.
        w2c_blender: `[N, 3, 4]` every row's view (only the environment-map rows use it).
        encoded: `[N]` bool, or None when every row is an environment map.
        encoded_ldr: `[Na, 3, size, size]` the pre-encoded LDR maps of the other rows.
        encoded_hdr: `[Na, 3, size, size]` their HDR maps.
        size: output side length.
        compat: gaffer-envmap encoding of the environment maps.
        device: where the result lives.

    Returns:
        `(ldr, hdr)`, each `[N, 3, size, size]` float32 in [0, 1] on `device`.

    Raises:
        DataError: the row counts or map sizes disagree.
    """
    n = int(w2c_blender.shape[0])
    if encoded is None or not bool(encoded.any()):
        if envmaps.shape[0] != n:
            raise DataError(f"{envmaps.shape[0]} environment maps for {n} views.")
        return encode_batch_lighting(envmaps, w2c_blender, size=size, compat=compat, device=device)
    enc = encoded.to(device="cpu", dtype=torch.bool)
    n_enc = int(enc.sum())
    if (
        enc.shape != (n,)
        or encoded_ldr is None
        or encoded_hdr is None
        or encoded_ldr.shape[0] != n_enc
        or encoded_hdr.shape[0] != n_enc
        or envmaps.shape[0] != n - n_enc
    ):
        raise DataError(
            f"`batch_lighting`: {n} views, `encoded` marks {n_enc}, but got {envmaps.shape[0]} "
            "environment maps and "
            f"{None if encoded_ldr is None else encoded_ldr.shape[0]} encoded maps."
        )
    if tuple(encoded_ldr.shape[1:]) != (3, size, size) or encoded_hdr.shape != encoded_ldr.shape:
        raise DataError(
            f"the encoded lighting maps are {tuple(encoded_ldr.shape[1:])}; expected (3, {size}, "
            f"{size}): read the dataset at the model resolution."
        )
    ldr = torch.empty(n, 3, size, size, device=device, dtype=torch.float32)
    hdr = torch.empty_like(ldr)
    ldr[enc.to(ldr.device)] = encoded_ldr.to(device=ldr.device, dtype=torch.float32)
    hdr[enc.to(hdr.device)] = encoded_hdr.to(device=hdr.device, dtype=torch.float32)
    if n_enc < n:
        env_ldr, env_hdr = encode_batch_lighting(
            envmaps, w2c_blender[~enc], size=size, compat=compat, device=device
        )
        ldr[~enc.to(ldr.device)] = env_ldr
        hdr[~enc.to(hdr.device)] = env_hdr
    return ldr, hdr


def batch_lighting_of(
    batch: TrainBatch,
    *,
    size: int,
    compat: LightingCompat,
    device: torch.device | str | None = None,
) -> tuple[Float[Tensor, "BT 3 S S"], Float[Tensor, "BT 3 S S"]]:
    """The `[B*T, 3, size, size]` LDR and HDR maps of every target of `batch` (item-major order)."""
    t = batch.targets_per_sample
    enc = batch.lighting_encoded
    return batch_lighting(
        batch.envmaps.flatten(0, 1),
        batch.w2c_blender.repeat_interleave(t, dim=0),
        encoded=None if enc is None else enc.repeat_interleave(t),
        encoded_ldr=None if batch.encoded_ldr is None else batch.encoded_ldr.flatten(0, 1),
        encoded_hdr=None if batch.encoded_hdr is None else batch.encoded_hdr.flatten(0, 1),
        size=size,
        compat=compat,
        device=device,
    )
