"""The target lighting of each pair as the model's camera-frame LDR/HDR maps."""

import functools
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image
from torch import Tensor

from gaffer_diffusion.conditioning import CompatMode, LightingMaps, lighting_from_envmap
from gaffer_diffusion.errors import DatasetError
from gaffer_diffusion.evaluation.records import EncodedLightingFiles, EvalPair


@functools.lru_cache(maxsize=8)
def _augmented_envmap(
    source: Path, flip: bool, yaw_step: int, num_steps: int, strength: float
) -> Any:
    from gaffer_envmap import AugmentSpec, EnvironmentMap
    from gaffer_envmap.io import read_envmap

    env = AugmentSpec(flip=flip, yaw_step=yaw_step, num_steps=num_steps).apply(
        read_envmap(source, sanitize="zero")
    )
    if strength != 1.0:
        env = EnvironmentMap(radiance_linear=np.asarray(env.radiance_linear) * np.float32(strength))
    return env


def read_lighting_map(path: Path, size: int) -> Tensor:
    """`[1, 3, size, size]` encoded lighting map in [0, 1] (PIL bilinear when resized, as the authors)."""
    try:
        with Image.open(path) as im:
            rgb = im.convert("RGB")
            if rgb.size != (size, size):
                rgb = rgb.resize((size, size), Image.Resampling.BILINEAR)
            arr = np.asarray(rgb, np.float32) / 255.0
    except (OSError, ValueError) as exc:
        raise DatasetError(f"Could not read the lighting map `{path}`: {exc}.") from exc
    return torch.from_numpy(arr).permute(2, 0, 1)[None].contiguous()


def pair_lighting(pairs: Sequence[EvalPair], size: int, compat: CompatMode) -> LightingMaps:
    """Camera-frame LDR/HDR maps of each pair's target lighting, `[B, 3, size, size]`.

    Env maps are augmented, rotated into the view's camera frame and encoded with `compat`; the
    authors' pre-encoded maps are read as they are (resized if the model resolution differs).

    Raises:
        DatasetError: when a map cannot be read or augmented.
    """
    ldr, hdr = [], []
    for p in pairs:
        lt = p.lighting
        if isinstance(lt, EncodedLightingFiles):
            ldr.append(read_lighting_map(lt.ldr, size))
            hdr.append(read_lighting_map(lt.hdr, size))
            continue
        try:
            env = _augmented_envmap(lt.source, lt.flip, lt.yaw_step, lt.num_steps, lt.strength)
        except (OSError, ValueError) as exc:
            raise DatasetError(
                f"Could not read or augment the environment map `{lt.source}` of `{p.name}`: {exc}"
            ) from exc
        w2c = torch.tensor(lt.w2c_blender[None])  # [1, 3, 4], a copy (the pose is read-only)
        maps = lighting_from_envmap(env, w2c, size=size, compat=compat)
        ldr.append(maps.ldr)
        hdr.append(maps.hdr)
    return LightingMaps(ldr=torch.cat(ldr), hdr=torch.cat(hdr))
