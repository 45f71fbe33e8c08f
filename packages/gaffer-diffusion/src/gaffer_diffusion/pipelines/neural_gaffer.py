"""`NeuralGafferPipeline`: the relighting model as a `diffusers.DiffusionPipeline`.

What diffusers users expect: `NeuralGafferPipeline.from_pretrained(DIR)(image, envmap).images[0]`.
It is the same model and the same sampling as `gaffer-diffusion relight PHOTO --envmap MAP --seed S`
(the photo's object framed as the model was trained, its own sampling from the model folder, the
relit object pasted back into the photo at the photo's size with the model's change of shading on the
full-resolution photo): it wraps `RelightPipeline` (`load_pipeline`) and the photo helpers the command
line uses, so the two give the same pixels. Local folders only: nothing is downloaded.
"""

import dataclasses
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from diffusers.pipelines.pipeline_utils import DiffusionPipeline
from diffusers.utils.outputs import BaseOutput
from PIL import Image

from gaffer_diffusion.errors import ConfigError
from gaffer_diffusion.models.model import NeuralGafferModel
from gaffer_diffusion.photo import Photo
from gaffer_diffusion.pipelines.config import DtypeName, RuntimeConfig
from gaffer_diffusion.pipelines.load import load_pipeline
from gaffer_diffusion.pipelines.relight import RelightPipeline
from gaffer_diffusion.suggested import DefaultSampling

ImageInput = str | Path | Image.Image
"""A photo: a file, or a PIL image (RGBA: its alpha marks the object)."""

StepEndCallback = Callable[[Any, int, int, dict[str, Any]], dict[str, Any] | None]
"""diffusers' `callback_on_step_end(pipeline, step, timestep, callback_kwargs)`."""

_DTYPE_NAMES: dict[torch.dtype, DtypeName] = {
    torch.float32: "float32",
    torch.float16: "float16",
    torch.bfloat16: "bfloat16",
}


@dataclasses.dataclass
class NeuralGafferPipelineOutput(BaseOutput):
    """What `NeuralGafferPipeline.__call__` returns.

    Attributes:
        images: the relit photo at the photo's size: a list of one PIL image (RGBA when the photo
            has alpha, which is kept) with `output_type="pil"`, else a `[1, H, W, C]` float32 array
            in [0, 1] (`output_type="np"`).
    """

    images: list[Image.Image] | np.ndarray


class NeuralGafferPipeline(DiffusionPipeline):
    """Neural Gaffer (paper §3.2) as a diffusers pipeline: relight the object of a photo under an
    environment map.

    Components (`register_modules`): `unet` (16 input channels: z_t and the latents of the photo and
    of the LDR and HDR maps), `vae` (diffusers' `AutoencoderKL`, or gaffer-tiny's pixel-space
    identity), `image_encoder` (CLIP) and `scheduler` (DDIM, the paper's). The model's own sampling
    (`default_sampling`, read once from its folder) gives the steps, guidance, mirror mean and
    lighting encoding that `__call__` leaves unset.

    Example:
        >>> from gaffer_diffusion import NeuralGafferPipeline
        >>> pipe = NeuralGafferPipeline.from_pretrained(None)  # the shipped gaffer-tiny  # doctest: +SKIP
        >>> pipe("photo.png", "studio.exr").images[0].save("relit.png")  # doctest: +SKIP
    """

    model_cpu_offload_seq = "image_encoder->unet->vae"

    def __init__(
        self,
        unet: Any,
        vae: Any,
        image_encoder: Any,
        scheduler: Any,
        relight: RelightPipeline | None = None,
    ) -> None:
        super().__init__()
        if (
            relight is None
        ):  # what the networks mean (residual target, hints) is in the model folder
            raise ConfigError(
                "Build a NeuralGafferPipeline with `NeuralGafferPipeline.from_pretrained(DIR)` or "
                "`from_relight_pipeline(pipe)`: the components alone do not say how to sample them."
            )
        self.register_modules(unet=unet, vae=vae, image_encoder=image_encoder, scheduler=scheduler)
        self._relight = relight

    @classmethod
    def from_relight_pipeline(cls, relight: RelightPipeline) -> "NeuralGafferPipeline":
        """Wrap a loaded `RelightPipeline` (its networks become this pipeline's components)."""
        from gaffer_diffusion.schedulers import make_scheduler

        m = relight.model
        scheduler = make_scheduler("ddim", m.config.scheduler)
        return cls(m.unet, m.vae, m.image_encoder, scheduler, relight=relight)

    @classmethod
    def from_pretrained(  # type: ignore[override]  # local folders only, with the base model
        cls,
        pretrained_model_name_or_path: str | Path | None = None,
        base_model: str | Path | None = None,
        *,
        torch_dtype: torch.dtype | None = None,
        device: str = "cpu",
        **kwargs: Any,
    ) -> "NeuralGafferPipeline":
        """Load a local model folder; nothing is downloaded.

        Args:
            pretrained_model_name_or_path: our folder (`gaffer_model.json`: `save_pretrained`,
                `gaffer-diffusion export`, training's `final/`), the authors' `checkpoint-80000/`
                (with `base_model`), or None for the shipped gaffer-tiny.
            base_model: the local Zero-1-to-3 XL diffusers folder the authors' release needs.
            torch_dtype: float32 (default), float16 or bfloat16.
            device: where the networks run.
            kwargs: refused (hub options such as `revision` have no meaning here).

        Raises:
            ConfigError: a hub-style option, or a model id that is not a local folder.
            CheckpointNotFoundError, CheckpointMismatchError: see `load_pipeline`.
        """
        if kwargs:
            raise ConfigError(
                f"NeuralGafferPipeline.from_pretrained takes a local folder only; {sorted(kwargs)} "
                "have no meaning here (nothing is downloaded)."
            )
        dtype = "float32" if torch_dtype is None else _DTYPE_NAMES.get(torch_dtype)
        if dtype is None:
            raise ConfigError(
                f"`torch_dtype` is {torch_dtype}; expected torch.float32, float16 or bfloat16."
            )
        relight = load_pipeline(
            pretrained_model_name_or_path,
            base_model,
            runtime=RuntimeConfig(device=device, dtype=dtype),
            flag="pretrained_model_name_or_path",
            base_model_flag="base_model",
        )
        return cls.from_relight_pipeline(relight)

    def save_pretrained(  # type: ignore[override]  # our folder format, which from_pretrained reads
        self, save_directory: str | Path, **kwargs: Any
    ) -> None:
        """Write the model in our folder format (`gaffer_diffusion.loading.save_pretrained`, with
        its `default_sampling`), which `from_pretrained` loads back."""
        from gaffer_diffusion.loading import save_pretrained

        if kwargs:
            raise ConfigError(
                f"NeuralGafferPipeline.save_pretrained writes a local folder only; {sorted(kwargs)} "
                "have no meaning here (nothing is uploaded)."
            )
        save_pretrained(self.model, save_directory, suggested=self.default_sampling)

    @property
    def model(self) -> NeuralGafferModel:
        """The networks as one `NeuralGafferModel`."""
        return self._relight.model

    @property
    def default_sampling(self) -> DefaultSampling:
        """The model's own sampling (read once from its folder)."""
        return self._relight.default_sampling

    def _relight_here(self) -> RelightPipeline:
        """The `RelightPipeline`, rebuilt when `.to(...)` moved the components since."""
        unet = self._relight.model.unet
        p = next(unet.parameters())
        if p.device != self._relight.device or p.dtype != self._relight.dtype:
            runtime = RuntimeConfig(
                device=str(p.device), dtype=_DTYPE_NAMES.get(p.dtype, "float32")
            )
            self._relight = RelightPipeline(
                self._relight.model,
                runtime,
                default_sampling=self._relight.default_sampling,
                source=self._relight.source,
            )
        return self._relight

    @torch.no_grad()
    def __call__(
        self,
        image: ImageInput,
        envmap: Any,
        w2c: Any = None,
        mask: Any = None,
        num_inference_steps: int | None = None,
        guidance_scale: float | None = None,
        generator: torch.Generator | int | None = None,
        output_type: str = "pil",
        callback_on_step_end: StepEndCallback | None = None,
    ) -> NeuralGafferPipelineOutput:
        """Relight the object of `image` under `envmap`, at the photo's size.

        Args:
            image: the photo (a file or a PIL image).
            envmap: the target lighting: an `.exr`/`.hdr` file or a `gaffer_envmap.EnvironmentMap`.
            w2c: the camera: a 3x4 / 4x4 world-to-camera matrix (Blender convention) or a
                `gaffer_envmap.poses.W2CBlender`; None: azimuth 0, elevation 0 (`--azimuth 0
                --elevation 0`).
            mask: the object: a mask file, a PIL image or an `[H, W]` array in [0, 1] (white =
                object); None: the photo's alpha, or a GrabCut estimate when it has none (as
                `gaffer-diffusion relight` does).
            num_inference_steps: denoising steps; None: the model's own.
            guidance_scale: classifier-free guidance scale; None: the model's own.
            generator: the seed (`--seed`): an int, or a CPU generator whose `initial_seed()` is
                used (every image is drawn from its own seeded generator, as the command line
                does); None: seed 0.
            output_type: "pil" or "np".
            callback_on_step_end: called as `(pipeline, step, timestep, {})` after every step.

        Returns:
            `NeuralGafferPipelineOutput` with `.images` at the photo's size.

        Raises:
            ConfigError, InputValueError: bad arguments (named), before any sampling.
        """
        from gaffer_diffusion.conditioning import RelightingConditions, lighting_from_envmap
        from gaffer_diffusion.photo import paste_back, prepare_photo

        if output_type not in ("pil", "np"):
            raise ConfigError(f"`output_type` is {output_type!r}; expected 'pil' or 'np'.")
        photo = _photo(image)
        alpha = _object_mask(photo, mask)
        env = _envmap(envmap)
        pose = _pose(w2c)
        seed = _seed(generator)
        pipe = self._relight_here()
        own = pipe.default_sampling
        sampling = own.override(
            num_inference_steps=num_inference_steps, guidance_scale=guidance_scale
        ).sampling_config()
        size = pipe.model.config.resolution
        prepared = prepare_photo(photo, alpha, size=size, compat=own.compat)
        lighting = lighting_from_envmap(env, [pose], size=size, compat=own.compat)
        step_callback: Callable[[int, int], None] | None = None
        if callback_on_step_end is not None:
            _, timesteps = pipe.img2img_timesteps(1.0, sampling)
            ts = [int(t) for t in timesteps]

            def _on_step(i: int, _n: int) -> None:
                callback_on_step_end(self, i, ts[i], {})

            step_callback = _on_step

        model_in = prepared.model_input
        cond = RelightingConditions(image=model_in.image, lighting=lighting, mask=model_in.mask)
        # one seeded CPU generator per image, as `relight --seed` (`relight_in_batches`) draws it
        relit = pipe(cond, sampling, seeds=[seed], callback=step_callback).images[0]
        out = paste_back(prepared, relit.float().cpu(), detail="transfer")
        if output_type == "np":
            return NeuralGafferPipelineOutput(images=(out.astype(np.float32) / 255.0)[None])
        return NeuralGafferPipelineOutput(images=[Image.fromarray(out)])


def _photo(image: ImageInput) -> Photo:
    from gaffer_diffusion.photo import read_photo

    if isinstance(image, Image.Image):  # through the file reader: one conversion rule
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "image.png"
            image.save(path, format="PNG")
            return read_photo(path)
    return read_photo(image)


def _object_mask(photo: Photo, mask: Any) -> np.ndarray:
    """The object mask as `gaffer-diffusion relight` takes it: given, else the photo's alpha, else
    GrabCut."""
    from gaffer_diffusion.photo import check_mask, object_alpha, read_mask, usable_alpha

    if isinstance(mask, str | Path):
        return object_alpha(photo, read_mask(mask, photo))
    if isinstance(mask, Image.Image):
        mask = np.asarray(mask.convert("L"), np.float32) / 255.0
    if mask is not None:
        arr = np.asarray(mask, np.float32)
        if arr.shape != photo.rgb.shape[:2]:
            raise ConfigError(
                f"`mask` has shape {arr.shape}; expected the photo's {photo.rgb.shape[:2]}."
            )
        check_mask(arr, "`mask`")
        return arr
    if usable_alpha(photo) is not None:
        return object_alpha(photo, None)
    from gaffer_diffusion import automask

    return automask.grabcut_mask(photo.rgb_u8)


def _envmap(envmap: Any) -> Any:
    from gaffer_envmap import EnvironmentMap
    from gaffer_envmap.io import read_envmap

    if isinstance(envmap, EnvironmentMap):
        return envmap
    if isinstance(envmap, str | Path):
        return read_envmap(envmap)
    raise ConfigError(
        f"`envmap` is a {type(envmap).__name__}; pass an .exr/.hdr path or a "
        "gaffer_envmap.EnvironmentMap."
    )


def _pose(w2c: Any) -> Any:
    from gaffer_envmap.poses import W2CBlender, orbit_w2c_blender

    if w2c is None:
        return orbit_w2c_blender(0.0, 0.0)
    if isinstance(w2c, W2CBlender):
        return w2c
    arr = np.asarray(w2c, np.float64)
    if arr.shape not in ((3, 4), (4, 4)) or not np.isfinite(arr).all():
        raise ConfigError(
            f"`w2c` has shape {arr.shape}; pass a finite 3x4 or 4x4 world-to-camera matrix."
        )
    return W2CBlender.from_array(arr)


def _seed(generator: torch.Generator | int | None) -> int:
    if generator is None:
        return 0
    if isinstance(generator, torch.Generator):
        return int(generator.initial_seed())
    if isinstance(generator, int) and not isinstance(generator, bool):
        return generator
    raise ConfigError(
        f"`generator` is a {type(generator).__name__}; pass an int seed or a torch.Generator."
    )


__all__ = ["NeuralGafferPipeline", "NeuralGafferPipelineOutput"]
