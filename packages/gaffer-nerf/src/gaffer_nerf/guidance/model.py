"""Which relighting model the 3D stages use, and the sampling it suggests.

- `suggested_sampling(model)`: the model's own setting (`ModelSampling`). A model built from the
  gaffer-tiny config (the shipped weights, passed by hand or not, or a retrain of that config) gets
  the setting its model card was measured with (`gaffer_diffusion.pretrained`: 1 step, guidance 1,
  mirror average, gaffer-envmap's "default" encoding); any other model the paper's (50 steps,
  guidance 3, "neural-gaffer" encoding).
- `load_relighting_model(...)`: a `--checkpoint` folder (ours or the authors' release), the shipped
  gaffer-tiny when none is given (as `gaffer-diffusion relight` does), or the random smoke model
  (`smoke_model`, built from gaffer-diffusion's public "tiny" config, not its test helpers).
"""

import logging
from dataclasses import dataclass
from pathlib import Path

from gaffer_diffusion import NeuralGafferModel, build_model, get_preset
from gaffer_nerf.configs import PAPER_SAMPLING, ModelSampling
from gaffer_nerf.errors import ConfigError

logger = logging.getLogger(__name__)

GAFFER_TINY_NAME = "gaffer-tiny"
"""`ModelConfig.name` of gaffer-tiny (`gaffer_diffusion.configs.get_preset("gaffer-tiny")`)."""


def gaffer_tiny_sampling() -> ModelSampling:
    """gaffer-tiny's suggested sampling, read from `gaffer_diffusion.pretrained`'s constants."""
    from gaffer_diffusion import pretrained

    compat = pretrained.GAFFER_TINY_COMPAT
    return ModelSampling(
        num_inference_steps=pretrained.GAFFER_TINY_STEPS,
        guidance_scale=pretrained.GAFFER_TINY_GUIDANCE,
        average_samples=pretrained.GAFFER_TINY_AVERAGE_SAMPLES,
        mirror_average=pretrained.GAFFER_TINY_MIRROR_AVERAGE,
        compat=compat,  # type: ignore[arg-type]
        # gaffer-diffusion relight: the posterior mode unless the encoding is the authors'
        latent_mode="sample" if compat == "neural-gaffer" else "mode",
        object_fraction=pretrained.GAFFER_TINY_OBJECT_FRACTION,
        source="gaffer-tiny's model card (gaffer_diffusion.pretrained)",
    )


def suggested_sampling(model: NeuralGafferModel) -> ModelSampling:
    """The sampling `model` suggests: gaffer-tiny's for the gaffer-tiny config, else the paper's.

    Example:
        >>> from gaffer_nerf.guidance.model import smoke_model
        >>> suggested_sampling(smoke_model()).num_inference_steps
        50
    """
    if model.config.name == GAFFER_TINY_NAME:
        return gaffer_tiny_sampling()
    return PAPER_SAMPLING


def smoke_model(seed: int = 0) -> NeuralGafferModel:
    """A RANDOM model of gaffer-diffusion's "tiny" config (64 px): wiring checks only, it relights nothing."""
    return build_model(get_preset("tiny"), seed=seed)


@dataclass(frozen=True, kw_only=True)
class RelightingModel:
    """A loaded relighting model, where it came from and its suggested sampling.

    Attributes:
        model: the networks.
        name: "gaffer-tiny", "random smoke model" or the checkpoint's config name.
        source: the weights folder (None for the random model).
        suggested: the model's own sampling (`suggested_sampling`).
    """

    model: NeuralGafferModel
    name: str
    source: Path | None
    suggested: ModelSampling

    def describe(self) -> str:
        """One line: the model, where from, and the sampling it suggests."""
        where = f" ({self.source})" if self.source is not None else ""
        return f"{self.name}{where}; its sampling: {self.suggested.describe()} [{self.suggested.source}]"


def load_relighting_model(
    checkpoint: Path | None,
    base_model: Path | None = None,
    *,
    smoke: bool = False,
    flag: str = "--checkpoint",
) -> RelightingModel:
    """The model for the 3D stages: `checkpoint`, else the shipped gaffer-tiny (or `smoke`'s random one).

    Args:
        checkpoint: a gaffer-diffusion model folder (`gaffer_model.json`) or the authors'
            `checkpoint-80000/` (with `base_model`); None: gaffer-tiny.
        base_model: the Zero-1-to-3 XL folder the authors' release needs.
        smoke: the random smoke model (`smoke_model`) instead; excludes `checkpoint`.
        flag: the checkpoint argument's name in messages.

    Raises:
        ConfigError: inconsistent arguments (named, with the fix).
        gaffer_diffusion.errors.CheckpointNotFoundError: missing weights (the file and how to get it).
    """
    from gaffer_diffusion import pretrained
    from gaffer_diffusion.loading import MANIFEST_NAME, load_authors_release, load_pretrained

    if smoke:
        if checkpoint is not None:
            raise ConfigError(
                f"`--diffusion-preset tiny` is a random smoke model; drop it or drop `{flag}`."
            )
        model = smoke_model()
        return RelightingModel(
            model=model,
            name="random smoke model (relights nothing)",
            source=None,
            suggested=suggested_sampling(model),
        )
    if checkpoint is None:
        if base_model is not None:
            raise ConfigError(f"`--base-model` goes with the authors' `{flag}`; pass both.")
        model = pretrained.load_gaffer_tiny().model
        return RelightingModel(
            model=model,
            name=f"gaffer-tiny (no `{flag}` given: the shipped 128 px model)",
            source=pretrained.gaffer_tiny_path(),
            suggested=suggested_sampling(model),
        )
    path = Path(checkpoint).expanduser()
    if not path.exists():
        raise ConfigError(
            f"`{flag}` {path} does not exist. Pass a model folder (one with {MANIFEST_NAME}) or the "
            f"authors' checkpoint-80000/ with `--base-model`, or leave `{flag}` out for gaffer-tiny."
        )
    if (path / MANIFEST_NAME).is_file():
        model = load_pretrained(path).model
    elif base_model is None:
        raise ConfigError(
            f"`{flag}` {path} is not a gaffer-diffusion folder (no {MANIFEST_NAME}), so it is taken "
            "as the authors' release, which needs `--base-model DIR` (Zero-1-to-3 XL)."
        )
    else:
        model = load_authors_release(path, base_model).model
    return RelightingModel(
        model=model, name=model.config.name, source=path, suggested=folder_sampling(path, model)
    )


def folder_sampling(folder: Path, model: NeuralGafferModel) -> ModelSampling:
    """The sampling a model folder records (`gaffer_diffusion.suggested`, written by `gaffer-diffusion
    export` and training's `final/`), else `suggested_sampling(model)`."""
    from gaffer_diffusion.suggested import PAPER_SUGGESTION, read_suggested_sampling

    own = read_suggested_sampling(folder)
    if own is PAPER_SUGGESTION:
        return suggested_sampling(model)
    return ModelSampling(
        num_inference_steps=own.num_inference_steps,
        guidance_scale=own.guidance_scale,
        average_samples=own.average_samples,
        mirror_average=own.mirror_average,
        compat=own.compat,
        latent_mode="sample" if own.compat == "neural-gaffer" else "mode",
        object_fraction=None if own.object_fraction is None else float(own.object_fraction),
        source=own.source,
    )
