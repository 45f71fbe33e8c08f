"""Which relighting model the 3D stages use, loaded once with the sampling its folder records.

`load_relighting_model(...)`: a `--checkpoint` folder (ours or the authors' release), the shipped
gaffer-tiny when none is given (as `gaffer-diffusion relight` does), both through
`gaffer_diffusion.load_pipeline`, or the random smoke model (`smoke_model`, built from
gaffer-diffusion's public "tiny" config, not its test helpers). The model's own sampling is the
pipeline's `default_sampling`; `DiffusionSamplingConfig.resolved` only overrides it.
"""

import logging
from dataclasses import dataclass
from pathlib import Path

from gaffer_diffusion import (
    DefaultSampling,
    LoadedModel,
    NeuralGafferModel,
    RelightPipeline,
    RuntimeConfig,
    build_model,
    get_preset,
    load_pipeline,
)
from gaffer_nerf.errors import ConfigError

logger = logging.getLogger(__name__)


def smoke_model(seed: int = 0) -> NeuralGafferModel:
    """A RANDOM model of gaffer-diffusion's "tiny" config (64 px): wiring checks only, it relights nothing."""
    return build_model(get_preset("tiny"), seed=seed)


@dataclass(frozen=True, kw_only=True)
class RelightingModel(LoadedModel):
    """A loaded relighting pipeline and the name reports give it (`gaffer_diffusion.LoadedModel`,
    shared with gaffer-diffusion's demo and app; `describe` is its one-line summary).

    Attributes:
        pipeline: the pipeline (its `default_sampling` is the model's own sampling).
        name: "gaffer-tiny (...)", "random smoke model" or the checkpoint's config name.
    """

    @property
    def suggested(self) -> DefaultSampling:
        """The model's own sampling (`RelightPipeline.default_sampling`), by the 3D stages' name."""
        return self.default_sampling


def load_relighting_model(
    checkpoint: Path | None,
    base_model: Path | None = None,
    *,
    smoke: bool = False,
    flag: str = "--checkpoint",
    runtime: RuntimeConfig | None = None,
) -> RelightingModel:
    """The model for the 3D stages: `checkpoint`, else the shipped gaffer-tiny (or `smoke`'s random one).

    Args:
        checkpoint: a gaffer-diffusion model folder (`gaffer_model.json`) or the authors'
            `checkpoint-80000/` (with `base_model`); None: gaffer-tiny.
        base_model: the Zero-1-to-3 XL folder the authors' release needs.
        smoke: the random smoke model (`smoke_model`) instead; excludes `checkpoint`.
        flag: the checkpoint argument's name in messages.
        runtime: device and precision (None: float32 on the CPU).

    Raises:
        ConfigError: inconsistent arguments or a missing `checkpoint` (named, with the fix).
        gaffer_diffusion.errors.CheckpointNotFoundError: missing weights (the file and how to get it).
    """
    if smoke:
        if checkpoint is not None:
            raise ConfigError(
                f"`--diffusion-preset tiny` is a random smoke model; drop it or drop `{flag}`."
            )
        return RelightingModel(
            pipeline=RelightPipeline(smoke_model(), runtime),
            name="random smoke model (relights nothing)",
        )
    if checkpoint is not None and not Path(checkpoint).expanduser().exists():
        raise ConfigError(
            f"`{flag}` {checkpoint} does not exist. Pass a model folder (one with gaffer_model.json) "
            f"or the authors' checkpoint-80000/ with `--base-model`, or leave `{flag}` out for "
            "gaffer-tiny."
        )
    pipe = load_pipeline(checkpoint, base_model, runtime=runtime, flag=flag)
    if checkpoint is None:
        name = f"gaffer-tiny (no `{flag}` given: the shipped 128 px model)"
    else:
        name = pipe.model.config.name
    return RelightingModel(pipeline=pipe, name=name)
