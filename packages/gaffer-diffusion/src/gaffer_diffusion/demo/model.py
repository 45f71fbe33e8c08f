"""The demo's model: `load_model` (a checkpoint in our format, or gaffer-tiny) and `sampling_for`
(the given DDIM settings, else the model's suggestion, else the paper's)."""

import logging
from dataclasses import dataclass
from pathlib import Path

from gaffer_diffusion import pretrained
from gaffer_diffusion.conditioning import CompatMode
from gaffer_diffusion.demo.config import DEFAULT_GUIDANCE, DEFAULT_STEPS
from gaffer_diffusion.errors import CheckpointNotFoundError, ConfigError
from gaffer_diffusion.loading import MANIFEST_NAME, load_pretrained
from gaffer_diffusion.models.model import NeuralGafferModel
from gaffer_diffusion.pipelines import SamplingConfig

logger = logging.getLogger("gaffer_diffusion.demo")  # the name log lines carried before the split


@dataclass(frozen=True, kw_only=True)
class LoadedModel:
    """A model and where it came from.

    Attributes:
        model: the networks.
        name: a label for reports ("gaffer-tiny", or the checkpoint's config name).
        source: the folder the weights were read from.
        suggested_steps: the denoising steps the model was evaluated with, if known.
        suggested_guidance: the guidance scale the model was evaluated with, if known.
        suggested_average: the samples averaged per image it was evaluated with, if known.
        suggested_mirror: whether it was evaluated with mirror averaging, if known.
        suggested_compat: the lighting encoding it was trained with, if known.
        suggested_object_fraction: the object framing it was trained with, if known.
    """

    model: NeuralGafferModel
    name: str
    source: Path
    suggested_steps: int | None = None
    suggested_guidance: float | None = None
    suggested_average: int | None = None
    suggested_mirror: bool | None = None
    suggested_compat: CompatMode | None = None
    suggested_object_fraction: float | None = None


def load_model(checkpoint: Path | None, *, flag: str = "--checkpoint") -> LoadedModel:
    """Load `checkpoint` (our format), or gaffer-tiny when it is None (and say so in the log).

    Args:
        checkpoint: a folder written by `save_pretrained` (e.g. `gaffer-diffusion init-random`, or
            training's `final/`); None for the shipped gaffer-tiny.
        flag: the argument's name in error messages.

    Raises:
        CheckpointNotFoundError: `checkpoint` does not exist, or gaffer-tiny's weights are missing
            (the message names the file looked for).
        ConfigError: `checkpoint` is not in our format (the authors' release needs `--base-model`,
            which `gaffer-diffusion relight` and `evaluate` take).
    """
    if checkpoint is None:
        return _load_gaffer_tiny(flag)
    path = Path(checkpoint).expanduser()
    if not path.exists():
        raise CheckpointNotFoundError(
            f"the model folder given as `{flag}`",
            [path],
            f"Pass an existing model folder as `{flag} DIR` (one with {MANIFEST_NAME}, e.g. from "
            f"`gaffer-diffusion init-random --out DIR`), or leave `{flag}` out to use gaffer-tiny.",
        )
    if not (path / MANIFEST_NAME).is_file():
        raise ConfigError(
            f"`{flag}` {path} is not a gaffer-diffusion model folder (no {MANIFEST_NAME}). The demo "
            "reads our format only; relight with the authors' release through `gaffer-diffusion "
            "relight --checkpoint checkpoint-80000/ --base-model DIR`."
        )
    model = load_pretrained(path).model
    from gaffer_diffusion.suggested import PAPER_SUGGESTION, read_suggested_sampling

    own = read_suggested_sampling(path)  # the sampling its folder records (training's, on export)
    if own is PAPER_SUGGESTION:
        return LoadedModel(model=model, name=model.config.name, source=path)
    return LoadedModel(
        model=model,
        name=model.config.name,
        source=path,
        suggested_steps=own.num_inference_steps,
        suggested_guidance=own.guidance_scale,
        suggested_average=own.average_samples,
        suggested_mirror=own.mirror_average,
        suggested_compat=own.compat,
        suggested_object_fraction=own.object_fraction,
    )


def sampling_for(
    loaded: LoadedModel,
    num_inference_steps: int | None,
    guidance_scale: float | None,
    average_samples: int | None = None,
    mirror_average: bool | None = None,
) -> SamplingConfig:
    """DDIM settings: the given values, else the model's suggestion, else the paper's (50, 3).

    Example:
        >>> from gaffer_diffusion.testing import tiny_model
        >>> m = LoadedModel(model=tiny_model(), name="x", source=Path("."), suggested_steps=20)
        >>> s = sampling_for(m, None, None)
        >>> s.num_inference_steps, s.guidance_scale
        (20, 3.0)
    """
    steps = (
        num_inference_steps
        if num_inference_steps is not None
        else loaded.suggested_steps or DEFAULT_STEPS
    )
    if guidance_scale is None:
        guidance_scale = (
            DEFAULT_GUIDANCE if loaded.suggested_guidance is None else loaded.suggested_guidance
        )
    average = average_samples if average_samples is not None else loaded.suggested_average or 1
    if mirror_average is None:
        mirror_average = bool(loaded.suggested_mirror)
    return SamplingConfig(
        num_inference_steps=steps,
        guidance_scale=guidance_scale,
        average_samples=average,
        mirror_average=mirror_average,
    )


def _load_gaffer_tiny(flag: str) -> LoadedModel:
    path = Path(pretrained.gaffer_tiny_path())
    if not (path / MANIFEST_NAME).is_file():
        raise CheckpointNotFoundError(
            "the gaffer-tiny weights",
            [path / MANIFEST_NAME],
            "gaffer-tiny ships inside the gaffer-diffusion package: reinstall it (`pip install "
            f"--force-reinstall gaffer-diffusion`), or pass a model folder as `{flag} DIR`.",
        )
    logger.info("no `%s` given: using gaffer-tiny, the shipped 128 px model (%s)", flag, path)
    return LoadedModel(
        model=pretrained.load_gaffer_tiny().model,
        name="gaffer-tiny",
        source=path,
        suggested_steps=pretrained.GAFFER_TINY_STEPS,
        suggested_guidance=pretrained.GAFFER_TINY_GUIDANCE,
        suggested_average=pretrained.GAFFER_TINY_AVERAGE_SAMPLES,
        suggested_mirror=pretrained.GAFFER_TINY_MIRROR_AVERAGE,
        suggested_compat=pretrained.GAFFER_TINY_COMPAT,  # type: ignore[arg-type]
        suggested_object_fraction=pretrained.GAFFER_TINY_OBJECT_FRACTION,
    )
