"""One training item read from disk: images composited on white, the view's pose, the lighting (the
environment maps of a render, or the authors' pre-encoded maps of a converted split), with the item's
random draws (input lighting, targets, exposure) taken from the generator it is given.

`read_render_item` and `read_authors_item` make the same draws in the same order, so an item depends
only on the dataset's `(seed, key)` whichever kind of dataset it comes from.
"""

from pathlib import Path

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

from gaffer_data.dataset import AuthorsObject, AuthorsView, RenderedObject, ViewRecord
from gaffer_diffusion.preprocess import load_rgba_on_white, object_square, read_alpha
from gaffer_diffusion.training.batch import TrainItem
from gaffer_diffusion.training.config import DataConfig
from gaffer_diffusion.training.envmaps import EnvmapCache
from gaffer_diffusion.training.exposure import exposure_gains, reexpose_on_white


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


def read_render_item(
    obj: RenderedObject,
    view: ViewRecord,
    w2c_blender: np.ndarray,
    rng: np.random.Generator,
    *,
    config: DataConfig,
    resolution: int,
    envmaps: EnvmapCache,
) -> TrainItem:
    """The item of one view of a gaffer-data render.

    Args:
        obj: the object.
        view: its view.
        w2c_blender: `[3, 4]` the view's world-to-camera matrix (Blender camera axes).
        rng: the item's generator (draws: input lighting, target order, then exposure / tint).
        config: sampling settings.
        resolution: image side length.
        envmaps: where the targets' environment maps are read.

    Raises:
        OSError, ValueError: an unreadable image or environment map.
    """
    t = config.targets_per_sample
    lit = view.lit
    # Neural Gaffer §3.1: 10% of inputs are the area-light render, else another envmap render
    draw = float(rng.random())
    use_area = view.area is not None and (draw < config.area_light_prob or len(lit) < t + 1)
    order = rng.permutation(len(lit))
    targets = [lit[i] for i in order[:t]]
    alpha = None if view.alpha is None else obj.path(view.alpha)
    size = resolution
    input_png = obj.path(
        view.area.png if use_area and view.area is not None else lit[int(order[t])].png
    )
    box = None
    if config.object_fraction is not None:
        # one square per view (input and targets alike): the object centred, filling the frame
        box = object_square(read_alpha(alpha or input_png), config.object_fraction)
    input_image, input_alpha = load_rgba_on_white(input_png, size, alpha, box)
    target_images = torch.stack(
        [load_image_on_white(obj.path(li.png), size, alpha, box) for li in targets]
    )
    maps = torch.stack(
        [torch.from_numpy(envmaps.get(li.envmap, obj.root.parent.parent).copy()) for li in targets]
    )
    a, b = config.target_exposure_stops, config.target_tint_stops
    if a > 0 or b > 0:
        # drawn after every other draw, so the rest of the item is as without the augmentation
        for j in range(t):
            stops = float(rng.uniform(-a, a)) + rng.uniform(-b, b, size=3)
            gains = exposure_gains(torch.from_numpy(stops), target_images[j], input_alpha)
            target_images[j] = reexpose_on_white(target_images[j], input_alpha, gains)
            maps[j] = maps[j] * gains.to(maps.dtype)
    return TrainItem(
        input_image=input_image,
        target_images=target_images,
        envmaps=maps,
        w2c_blender=torch.from_numpy(w2c_blender.copy()),
        input_is_area=bool(use_area),
        object_id=obj.object_id,
        view_index=view.index,
        input_alpha=input_alpha,
    )


def read_authors_item(
    obj: AuthorsObject,
    view: AuthorsView,
    w2c_blender: np.ndarray,
    rng: np.random.Generator,
    *,
    config: DataConfig,
    resolution: int,
) -> TrainItem:
    """The item of one view of a converted authors' split: the same draws as `read_render_item`, the
    authors' encoded maps as its lighting.

    Raises:
        OSError, ValueError: an unreadable image or lighting map.
    """
    # evaluation's reader of the authors' maps: RGB, PIL bilinear when resized, [1, 3, S, S]
    from gaffer_diffusion.evaluation import read_lighting_map

    t = config.targets_per_sample
    lit = view.lit
    draw = float(rng.random())
    use_area = view.area_png is not None and (draw < config.area_light_prob or len(lit) < t + 1)
    order = rng.permutation(len(lit))
    targets = [lit[i] for i in order[:t]]
    size = resolution
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
        w2c_blender=torch.from_numpy(w2c_blender.copy()),
        input_is_area=bool(use_area),
        object_id=obj.object_id,
        view_index=view.index,
    )
