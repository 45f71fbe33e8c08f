"""`gaffer-tiny`: the small pixel-space relighting model trained by this project and shipped in the wheel.

The weights live in `gaffer_diffusion/weights/gaffer-tiny/` in our own format (`save_pretrained`), with
`MODEL_CARD.md` (data, commands, training time, held-out numbers). A held-out example object rendered
with gaffer-data lives in `gaffer_diffusion/data/example/` (`example_dataset_path()`).

Example:
    >>> from gaffer_diffusion import RelightPipeline
    >>> from gaffer_diffusion.pretrained import load_gaffer_tiny
    >>> pipe = RelightPipeline(load_gaffer_tiny().model)  # doctest: +SKIP
"""

from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

from gaffer_diffusion._choices import MANIFEST_NAME
from gaffer_diffusion.errors import CheckpointNotFoundError

# `loading` imports torch and diffusers; the CLI reads this module's constants first
if TYPE_CHECKING:
    from gaffer_diffusion.loading import LoadResult

GAFFER_TINY_STEPS = 1
"""DDIM steps gaffer-tiny was evaluated with (its model card's numbers); the suggested default."""

GAFFER_TINY_GUIDANCE = 1.0
"""Classifier-free guidance scale gaffer-tiny was evaluated with."""

GAFFER_TINY_AVERAGE_SAMPLES = 1
"""Samples averaged per output (`SamplingConfig.average_samples`) in gaffer-tiny's suggested setting."""

GAFFER_TINY_MIRROR_AVERAGE = True
"""Whether gaffer-tiny's suggested setting averages with the mirrored input (`SamplingConfig.mirror_average`)."""

GAFFER_TINY_COMPAT = "default"
"""The lighting encoding gaffer-tiny was trained with (gaffer-envmap's default, not the authors')."""

GAFFER_TINY_OBJECT_FRACTION = 0.75
"""The framing gaffer-tiny was trained with: object-centred square crops in which the object's longer
side spans 75% (`DataConfig.object_fraction`; `prepare_object_image`'s default for photos)."""

_HOW = (
    "gaffer-tiny ships inside the gaffer-diffusion package (`gaffer_diffusion/weights/gaffer-tiny/`). "
    "Reinstall the package (`pip install --force-reinstall gaffer-diffusion`), or retrain it with "
    "`gaffer-diffusion train --config packages/gaffer-diffusion/configs/gaffer-tiny.json`, then "
    "`gaffer-tiny-stage2.json`, on the renders its MODEL_CARD.md lists, export the chosen step with "
    "`gaffer-diffusion export`, and load that folder with `gaffer_diffusion.loading.load_pretrained`."
)


def _package_dir(*parts: str) -> Path:
    return Path(str(resources.files("gaffer_diffusion").joinpath(*parts)))


def gaffer_tiny_path() -> Path:
    """The folder of the shipped gaffer-tiny weights (it may be missing in a stripped install)."""
    return _package_dir("weights", "gaffer-tiny")


def example_dataset_path() -> Path:
    """The shipped held-out example object, a gaffer-data render folder (`dataset.json`, `objects/`)."""
    return _package_dir("data", "example")


def load_gaffer_tiny(*, strict: bool = True) -> "LoadResult":
    """Load gaffer-tiny (float32, CPU, eval mode); `RelightPipeline(load_gaffer_tiny().model)` samples.

    Args:
        strict: refuse weights that do not match the config (see `load_pretrained`).

    Raises:
        CheckpointNotFoundError: the weights folder, its manifest or a weights file is missing; the
            message names the file and how to get it.
    """
    root = gaffer_tiny_path()
    weights = root / "unet" / "diffusion_pytorch_model.safetensors"
    for needed, what in (
        (root / MANIFEST_NAME, "the gaffer-tiny manifest"),
        (weights, "the gaffer-tiny UNet weights"),
    ):
        if not needed.is_file():
            raise CheckpointNotFoundError(what, [needed], _HOW)
    from gaffer_diffusion.loading import load_pretrained

    return load_pretrained(root, strict=strict)


__all__ = [
    "GAFFER_TINY_AVERAGE_SAMPLES",
    "GAFFER_TINY_COMPAT",
    "GAFFER_TINY_GUIDANCE",
    "GAFFER_TINY_MIRROR_AVERAGE",
    "GAFFER_TINY_OBJECT_FRACTION",
    "GAFFER_TINY_STEPS",
    "example_dataset_path",
    "gaffer_tiny_path",
    "load_gaffer_tiny",
]
