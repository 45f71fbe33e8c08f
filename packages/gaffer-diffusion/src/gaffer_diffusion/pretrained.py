"""`gaffer-tiny`: the small pixel-space relighting model trained by this project and shipped in the wheel.

The weights live in `gaffer_diffusion/weights/gaffer-tiny/` in our own format (`save_pretrained`), with
`MODEL_CARD.md` (data, commands, training time, held-out numbers); how it is meant to be sampled is
recorded once, in its `gaffer_model.json` (`suggested_sampling`, which `gaffer_diffusion.load_pipeline()`
reads into `default_sampling`). A held-out
example object rendered with gaffer-data lives in `gaffer_diffusion/data/example/`
(`example_dataset_path()`).

Example:
    >>> from gaffer_diffusion import load_pipeline
    >>> pipe = load_pipeline()  # gaffer-tiny  # doctest: +SKIP
"""

from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

from gaffer_diffusion._choices import MANIFEST_NAME
from gaffer_diffusion.errors import CheckpointNotFoundError

# `loading` imports torch and diffusers; the CLI imports this module before it checks its flags
if TYPE_CHECKING:
    from gaffer_diffusion.loading import LoadResult
    from gaffer_diffusion.suggested import DefaultSampling

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


def gaffer_tiny_sampling() -> "DefaultSampling":
    """How gaffer-tiny is meant to be sampled: what its folder's manifest records (a JSON read)."""
    from gaffer_diffusion.suggested import read_default_sampling

    return read_default_sampling(gaffer_tiny_path())


def example_dataset_path() -> Path:
    """The shipped held-out example object, a gaffer-data render folder (`dataset.json`, `objects/`)."""
    return _package_dir("data", "example")


def not_our_folder_message(root: Path, flag: str, base_model_flag: str | None) -> str:
    """The refusal of a folder without our manifest and without a base model (torch-free, so the
    command line says it before loading anything)."""
    what = f"`{flag}` {root} is not a gaffer-diffusion model folder (no {MANIFEST_NAME})"
    if base_model_flag is None:
        return (
            f"{what}. Only our format loads here; relight with the authors' release through "
            "`gaffer-diffusion relight --checkpoint checkpoint-80000/ --base-model DIR`."
        )
    return (
        f"{what}, so it is taken as the authors' release, which needs `{base_model_flag} DIR` (a "
        "local Zero-1-to-3 XL diffusers folder with vae/, image_encoder/, scheduler/, "
        "unet/config.json)."
    )


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
    "example_dataset_path",
    "gaffer_tiny_path",
    "gaffer_tiny_sampling",
    "load_gaffer_tiny",
    "not_our_folder_message",
]
