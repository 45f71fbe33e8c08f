"""`load_pipeline`: the one way a model folder becomes a `RelightPipeline` (CLI, demo, app, evaluate,
gaffer-nerf).

Three kinds of folder (official implementation §1): ours (`gaffer_model.json`, written by
`save_pretrained` / `gaffer-diffusion export`), the shipped gaffer-tiny (ours too, inside the package;
the default when no folder is given), and the authors' `checkpoint-80000/` with the Zero-1-to-3 XL
folder it needs. The model's own sampling (`DefaultSampling`) is read from the same folder once, here,
and frozen on the pipeline as `default_sampling`; callers only override it.
"""

import logging
from dataclasses import dataclass
from pathlib import Path

from gaffer_diffusion import pretrained
from gaffer_diffusion._choices import MANIFEST_NAME
from gaffer_diffusion.errors import CheckpointNotFoundError, ConfigError
from gaffer_diffusion.models.model import NeuralGafferModel
from gaffer_diffusion.pipelines.config import RuntimeConfig
from gaffer_diffusion.pipelines.relight import RelightPipeline
from gaffer_diffusion.suggested import DefaultSampling, read_default_sampling

logger = logging.getLogger(__name__)


def load_pipeline(
    path: str | Path | None = None,
    base_model: str | Path | None = None,
    *,
    runtime: RuntimeConfig | None = None,
    strict: bool = True,
    flag: str = "--checkpoint",
    base_model_flag: str | None = "--base-model",
) -> RelightPipeline:
    """Load a model folder into a `RelightPipeline` whose `default_sampling` the folder records.

    Args:
        path: our model folder (`gaffer_model.json`), the authors' `checkpoint-80000/` (with
            `base_model`), or None for the shipped gaffer-tiny.
        base_model: the local Zero-1-to-3 XL diffusers folder the authors' release needs.
        runtime: device and precision (None: float32 on the CPU).
        strict: refuse weights that do not match their configs (`load_pretrained`).
        flag: the argument's name in error messages.
        base_model_flag: the base model argument's name in messages; None where the caller takes
            none (the demo), so the message points to `gaffer-diffusion relight` instead.

    Returns:
        The pipeline; `pipeline.default_sampling` is the model's own sampling (the paper's for the
        authors' release or a folder that records none) and `pipeline.source` the folder read.

    Raises:
        CheckpointNotFoundError: `path` does not exist, or gaffer-tiny's weights are missing (the
            message names the file looked for and how to get it).
        ConfigError: `base_model` without the authors' `path`, or a folder that is not ours without
            `base_model`.
        CheckpointMismatchError: weights that do not match their configs (with `strict`).

    Example:
        >>> from gaffer_diffusion import load_pipeline
        >>> pipe = load_pipeline()  # doctest: +SKIP
        >>> pipe.default_sampling.num_inference_steps  # doctest: +SKIP
        1
    """
    from gaffer_diffusion.loading import load_authors_release, load_pretrained

    if path is None:
        if base_model is not None:
            raise ConfigError(
                f"`{base_model_flag or 'base_model'}` goes with the authors' `{flag}`; pass both."
            )
        root = Path(pretrained.gaffer_tiny_path())
        if not (root / MANIFEST_NAME).is_file():
            raise CheckpointNotFoundError(
                "the gaffer-tiny weights",
                [root / MANIFEST_NAME],
                "gaffer-tiny ships inside the gaffer-diffusion package: reinstall it (`pip install "
                f"--force-reinstall gaffer-diffusion`), or pass a model folder as `{flag} DIR`.",
            )
        logger.info("no `%s` given: using gaffer-tiny, the shipped 128 px model (%s)", flag, root)
        model = pretrained.load_gaffer_tiny(strict=strict).model
    else:
        root = Path(path).expanduser()
        if not root.exists():
            raise CheckpointNotFoundError(
                f"the model folder given as `{flag}`",
                [root],
                f"Pass an existing model folder as `{flag} DIR` (one with {MANIFEST_NAME}, e.g. from "
                f"`gaffer-diffusion init-random --out DIR`) or the authors' checkpoint-80000/, or "
                f"leave `{flag}` out to use gaffer-tiny.",
            )
        if (root / MANIFEST_NAME).is_file():
            model = load_pretrained(root, strict=strict).model
        elif base_model is None:
            raise ConfigError(pretrained.not_our_folder_message(root, flag, base_model_flag))
        else:
            result = load_authors_release(root, base_model, strict=strict)
            logger.info("%s", result.report.summary())
            model = result.model
    return RelightPipeline(
        model, runtime, default_sampling=read_default_sampling(root), source=root
    )


@dataclass(frozen=True, kw_only=True)
class LoadedModel:
    """A loaded pipeline and the label reports give it: what the demo, the app and gaffer-nerf's
    stages hold (gaffer-nerf's `RelightingModel` adds only its own names).

    Attributes:
        pipeline: the pipeline, with the model's own sampling (`default_sampling`).
        name: a label for reports ("gaffer-tiny", the checkpoint's config name, the app's label).
    """

    pipeline: RelightPipeline
    name: str

    @property
    def model(self) -> NeuralGafferModel:
        """The networks."""
        return self.pipeline.model

    @property
    def source(self) -> Path | None:
        """The folder the weights were read from (None: built in memory)."""
        return self.pipeline.source

    @property
    def default_sampling(self) -> DefaultSampling:
        """How the model is meant to be sampled (read once from its folder)."""
        return self.pipeline.default_sampling

    def describe(self) -> str:
        """One line: the model, where from, and the sampling it suggests."""
        where = f" ({self.source})" if self.source is not None else ""
        own = self.default_sampling
        return f"{self.name}{where}; its sampling: {own.describe()} [{own.source}]"


__all__ = ["LoadedModel", "load_pipeline"]
