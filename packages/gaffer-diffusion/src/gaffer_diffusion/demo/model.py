"""The demo's model: `load_model` (`load_pipeline` with the demo's messages, giving the shared
`gaffer_diffusion.LoadedModel`) and `sampling_for` (the model's own sampling,
`RelightPipeline.default_sampling`, with the values given)."""

from pathlib import Path

from gaffer_diffusion.conditioning import CompatMode
from gaffer_diffusion.pipelines import LoadedModel, RuntimeConfig, SamplingConfig, load_pipeline


def load_model(
    checkpoint: Path | None,
    *,
    flag: str = "--checkpoint",
    base_model: Path | None = None,
    runtime: RuntimeConfig | None = None,
    name: str | None = None,
) -> LoadedModel:
    """Load `checkpoint` (our format, or the authors' with `base_model`), or gaffer-tiny when it is
    None (and say so in the log); see `gaffer_diffusion.load_pipeline`.

    Args:
        checkpoint: a folder written by `save_pretrained` (e.g. `gaffer-diffusion init-random`, or
            training's `final/`); None for the shipped gaffer-tiny.
        flag: the argument's name in error messages.
        base_model: the Zero-1-to-3 XL folder of the authors' release (the app's picker); without
            it only our format loads.
        runtime: device and precision (None: float32 on the CPU).
        name: the label (None: "gaffer-tiny", or the model config's name).

    Raises:
        CheckpointNotFoundError: `checkpoint` does not exist, or gaffer-tiny's weights are missing
            (the message names the file looked for).
        ConfigError: `checkpoint` is not in our format and no `base_model` is given.
    """
    pipe = load_pipeline(
        checkpoint,
        base_model,
        runtime=runtime,
        flag=flag,
        base_model_flag=None if base_model is None else "base_model",
    )
    if name is None:
        name = "gaffer-tiny" if checkpoint is None else pipe.model.config.name
    return LoadedModel(pipeline=pipe, name=name)


def sampling_for(
    loaded: LoadedModel,
    num_inference_steps: int | None,
    guidance_scale: float | None,
    average_samples: int | None = None,
    mirror_average: bool | None = None,
    compat: CompatMode | None = None,
) -> SamplingConfig:
    """The model's own sampling (`default_sampling`; the paper's 50 steps, guidance 3 for a model
    that records none) with every value that is given instead; the latent mode is the one the
    encoding brings (`latent_mode_for`).

    Example:
        >>> from gaffer_diffusion import RelightPipeline
        >>> from gaffer_diffusion.testing import tiny_model
        >>> m = LoadedModel(pipeline=RelightPipeline(tiny_model()), name="x")
        >>> s = sampling_for(m, 20, None)
        >>> s.num_inference_steps, s.guidance_scale
        (20, 3.0)
    """
    return loaded.default_sampling.override(
        num_inference_steps=num_inference_steps,
        guidance_scale=guidance_scale,
        average_samples=average_samples,
        mirror_average=mirror_average,
        compat=compat,
    ).sampling_config()
