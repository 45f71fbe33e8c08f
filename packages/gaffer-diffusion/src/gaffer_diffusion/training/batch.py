"""Training samples and batches: `TrainItem` (one object view), `TrainBatch` and `collate_items`.

Records only: reading an item is `gaffer_diffusion.training.reading`, encoding a batch's lighting
`gaffer_diffusion.training.lighting`.
"""

from collections.abc import Sequence
from dataclasses import dataclass

import torch
from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion.training.errors import DataError


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
