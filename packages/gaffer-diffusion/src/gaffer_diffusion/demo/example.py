"""Reading the example object: one view of a gaffer-data render, its input and scored targets."""

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from gaffer_diffusion.demo.config import InputChoice
from gaffer_diffusion.errors import DatasetError, MissingDependencyError
from gaffer_diffusion.evaluation import EnvmapLighting, EvalPair, InputLighting, dataset_pairs


@dataclass(frozen=True, kw_only=True)
class _Example:
    """One view of the example object: the input and every scored target, at the model resolution."""

    pairs: tuple[EvalPair, ...]
    input_rgb: Tensor  # [1, 3, S, S] on white
    input_alpha: Tensor  # [1, 1, S, S]
    targets: Tensor  # [P, 3, S, S] on white
    masks: Tensor  # [P, 1, S, S]
    w2c_blender: np.ndarray  # [3, 4]


def _require_gaffer_data() -> None:
    try:
        import gaffer_data.dataset  # noqa: F401
    except ImportError as exc:
        raise MissingDependencyError(
            "The demo reads its example object with gaffer-data: "
            'pip install "gaffer-diffusion[eval]"'
        ) from exc


def _auto_input(root: Path) -> InputLighting:
    from gaffer_data.dataset import open_dataset

    for obj in open_dataset(root).iter_objects():
        for view in obj.views:
            return "area" if view.area is not None else 0
    raise DatasetError(f"`--example` {root} holds no complete object (objects/*/manifest.json).")


def _read_example(
    root: Path, choice: InputChoice, size: int, object_fraction: float | None = None
) -> _Example:
    from gaffer_diffusion.evaluation import pair_crop_box, read_mask, read_rgba_on_white
    from gaffer_envmap.bundled import bundled_hdris

    _require_gaffer_data()
    from gaffer_data import GafferDataError

    if not (root / "objects").is_dir():
        raise DatasetError(
            f"`--example` {root} is not a gaffer-data render folder (no objects/ in it). Pass a "
            "folder written by `gaffer-data render`, or leave `--example` out for the shipped one."
        )
    hdri_dir = next(iter(bundled_hdris().values())).parent
    try:
        input_lighting = _auto_input(root) if choice == "auto" else choice
        pairs = dataset_pairs(root, input_lighting=input_lighting, envmap_dirs=[hdri_dir])
    except GafferDataError as exc:
        raise DatasetError(f"`--example` {root} cannot be read: {exc}") from exc
    first = pairs[0]
    # one view of one object: the demo relights a single input image
    pairs = tuple(
        p for p in pairs if (p.object_id, p.view_index) == (first.object_id, first.view_index)
    )
    if not isinstance(first.lighting, EnvmapLighting):
        raise DatasetError(
            f"`--example` {root} is a converted authors' dataset (pre-encoded maps, no env maps or "
            "poses): the demo needs a gaffer-data render. Score it with `gaffer-diffusion evaluate`."
        )
    box = pair_crop_box(first, object_fraction)  # one view: one object-centred square
    input_rgb, input_alpha = read_rgba_on_white(first.input_image, size, box)
    targets, masks = [], []
    for p in pairs:
        rgb, alpha = read_rgba_on_white(p.target_image, size, box)
        targets.append(rgb)
        masks.append(alpha if p.mask is None else read_mask(p.mask, size, box))
    return _Example(
        pairs=pairs,
        input_rgb=_chw(np.stack([input_rgb])),
        input_alpha=torch.from_numpy(input_alpha)[None, None].float().contiguous(),
        targets=_chw(np.stack(targets)),
        masks=torch.from_numpy(np.stack(masks))[:, None].float().contiguous(),
        w2c_blender=np.asarray(first.lighting.w2c_blender, np.float64),
    )


def _chw(arr: np.ndarray) -> Tensor:
    return torch.from_numpy(np.ascontiguousarray(arr)).permute(0, 3, 1, 2).float().contiguous()
