"""The names the command line offers as choices, in a module that imports neither torch nor diffusers.

`gaffer-diffusion` builds its parser and checks its arguments from these before it imports torch or
loads a model, so that a refusal takes well under a second. The modules that use them
(`photo`, `preprocess`, `schedulers`, `conditioning`, `configs`, `loading`) import them from here.
"""

from typing import Literal

from gaffer_envmap.compat_mode import Compat

OutputSize = Literal["input", "model"]
"""`input`: the photo's own size, object pasted back (default); `model`: the model's square crop."""

DetailMode = Literal["transfer", "resize"]
"""How the low-resolution result reaches full size: shading ratio on the photo, or bicubic upsampling."""

Background = Literal["input", "envmap"]
"""Around the object: the photo's own pixels, or the target environment as the camera sees it."""

ShadowMode = Literal["2d", "cycles", "none"]
"""`gaffer-diffusion insert --shadow`: a pixel-height shadow cast on the ground plane from the mask
(`2d`), Blender's shadow catcher (`cycles`, not built yet), or none."""

SHADOW_MODES: tuple[ShadowMode, ...] = ("2d", "cycles", "none")

BACKDROP_FOV_DEG = 39.6
"""Horizontal field of view of the `--background envmap` camera: Blender's default 50 mm lens on 36 mm."""

PrepareCompat = Compat
"""How an object photo becomes the model's input: ours (`prepare_object_image`) or the authors' steps.
The same two modes, with the same meaning (gaffer's corrected pipeline or the authors' bit for bit), as
the lighting encoding: `gaffer_envmap.compat_mode.Compat`, not spelled out again."""

SchedulerName = Literal["ddim", "dpmpp-2m", "unipc", "dpmsolver++"]
"""Sampler names accepted by `make_scheduler` and the pipeline: the paper's DDIM, DPM-Solver++ (2M),
UniPC; "dpmsolver++" is the earlier spelling of "dpmpp-2m" (the same sampler)."""

SCHEDULERS: tuple[SchedulerName, ...] = ("ddim", "dpmpp-2m", "unipc", "dpmsolver++")

MULTISTEP_SCHEDULERS: tuple[SchedulerName, ...] = ("dpmpp-2m", "unipc", "dpmsolver++")
"""The samplers that reuse earlier steps' predictions (second order): they need 2 steps or more and
take no DDIM `eta`."""

LatentMode = Literal["mode", "sample"]
"""How conditioning latents are taken from the VAE posterior: its mode (default) or a sample (authors)."""

PresetName = Literal["neural-gaffer-256", "neural-gaffer-512", "tiny", "gaffer-tiny"]

PRESETS: tuple[PresetName, ...] = ("neural-gaffer-256", "neural-gaffer-512", "tiny", "gaffer-tiny")

MANIFEST_NAME = "gaffer_model.json"
"""The file that marks a model folder in our format (`gaffer_diffusion.loading.MANIFEST_NAME`)."""
