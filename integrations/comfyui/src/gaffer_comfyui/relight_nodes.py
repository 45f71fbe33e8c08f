"""Model and relighting nodes: load a model, relight a photo under a map, spin the light (turntable).

They compose gaffer-diffusion's public calls as `gaffer-diffusion relight` does (`_relight.py`), so the
Relight node's IMAGE equals the command's PNG (the tests compare them on the shipped example photo).
"""

from pathlib import Path
from typing import Any

from ._boundary import Progress, comfy_device, comfy_models_dir, library_errors
from ._convert import MASK_SENSES, check_image, object_alphas, photo_items, to_image, to_mask
from ._relight import (
    RelightJob,
    camera_pose,
    check_choice,
    check_envmap,
    check_model,
    relight_item,
    sampling_for,
)
from .errors import NodeInputError
from .types import GAFFER_ENVMAP, GAFFER_MODEL, GafferModel

CATEGORY = "Neural Gaffer"

DEVICES = ("auto", "cpu", "cuda")
DTYPES = ("float32", "float16", "bfloat16")
OUTPUT_SIZES = ("input", "model")
"""`gaffer_diffusion.photo.OutputSize`: the photo's own size (object pasted back) or the model's crop."""
DETAIL_MODES = ("transfer", "resize")
"""`gaffer_diffusion.photo.DetailMode`."""
BACKGROUNDS = ("input", "envmap")
"""`gaffer_diffusion.photo.Background`."""

MODEL_SUBFOLDER = "neural_gaffer"
"""Inside ComfyUI: a relative `model` folder is looked up in `models/neural_gaffer/` too."""


def _resolve_dir(node: str, name: str, text: str, what: str) -> Path:
    path = Path(text).expanduser()
    models = comfy_models_dir()
    if not path.is_absolute() and not path.exists() and models is not None:
        path = models / MODEL_SUBFOLDER / path
    if not path.is_dir():
        raise NodeInputError(f"{node}: `{name}` {text!r} is not an existing folder; give {what}.")
    return path


class NeuralGafferLoadModel:
    """Load the relighting model: the shipped gaffer-tiny, one of our model folders, or the authors'
    Neural Gaffer release with its Zero-1-to-3 XL base."""

    CATEGORY = CATEGORY
    FUNCTION = "load"
    RETURN_TYPES = (GAFFER_MODEL,)
    RETURN_NAMES = ("model",)
    DESCRIPTION = (
        "`model`: 'gaffer-tiny' (shipped, 128 px, offline), a gaffer-diffusion model folder (with "
        "gaffer_model.json), or the authors' checkpoint-80000/ with `base_model` set to a local "
        "Zero-1-to-3 XL diffusers folder. Sampling defaults come from the model's own folder."
    )

    @classmethod
    def INPUT_TYPES(cls) -> dict[str, Any]:
        return {
            "required": {
                "model": (
                    "STRING",
                    {
                        "default": "gaffer-tiny",
                        "tooltip": "'gaffer-tiny', a model folder, or the authors' checkpoint-80000/ "
                        "(absolute, or under ComfyUI's models/neural_gaffer/)",
                    },
                ),
                "base_model": (
                    "STRING",
                    {
                        "default": "",
                        "tooltip": "the authors' release only: a local Zero-1-to-3 XL diffusers "
                        "folder (vae/, image_encoder/, scheduler/, unet/config.json)",
                    },
                ),
                "device": (
                    list(DEVICES),
                    {"default": "auto", "tooltip": "auto: ComfyUI's device (else cuda if any)"},
                ),
                "dtype": (list(DTYPES), {"default": "float32"}),
            }
        }

    def load(self, model: str, base_model: str, device: str, dtype: str) -> tuple[GafferModel]:
        node = "NeuralGafferLoadModel"
        check_choice(node, "device", device, DEVICES)
        check_choice(node, "dtype", dtype, DTYPES)
        import torch

        dev = comfy_device() if device == "auto" else device
        if dev.startswith("cuda") and not torch.cuda.is_available():
            raise NodeInputError(
                f"{node}: `device` {device!r}: this torch ({torch.__version__}) sees no CUDA GPU; "
                "set `device` to cpu."
            )
        from gaffer_diffusion import pretrained
        from gaffer_diffusion.loading import MANIFEST_NAME, load_authors_release, load_pretrained
        from gaffer_diffusion.pipelines import RelightPipeline, RuntimeConfig
        from gaffer_diffusion.suggested import read_suggested_sampling

        name, base = str(model).strip(), str(base_model).strip()
        if name in ("", "gaffer-tiny"):
            if base:
                raise NodeInputError(
                    f"{node}: `base_model` goes with the authors' release; clear it for gaffer-tiny."
                )
            folder = pretrained.gaffer_tiny_path()
            with library_errors(node, "`model` gaffer-tiny"):
                net = pretrained.load_gaffer_tiny().model
            label = "gaffer-tiny"
        else:
            folder = _resolve_dir(node, "model", name, "a model folder or checkpoint-80000/")
            if (folder / MANIFEST_NAME).is_file():
                if base:
                    raise NodeInputError(
                        f"{node}: `model` {folder.name} is a gaffer-diffusion model folder; "
                        "`base_model` goes with the authors' release only: clear it."
                    )
                with library_errors(node, f"`model` {folder.name}"):
                    net = load_pretrained(folder).model
            else:
                if not base:
                    raise NodeInputError(
                        f"{node}: `model` {folder} is not a gaffer-diffusion model folder (no "
                        f"{MANIFEST_NAME}), so it is taken as the authors' release, which needs "
                        "`base_model`: a local Zero-1-to-3 XL diffusers folder."
                    )
                base_dir = _resolve_dir(node, "base_model", base, "a Zero-1-to-3 XL folder")
                with library_errors(node, f"`model` {folder.name} with `base_model`"):
                    net = load_authors_release(folder, base_dir).model
            label = str(net.config.name)
        with library_errors(node, f"`model` {label}"):
            suggested = read_suggested_sampling(folder)
            # as `relight --dtype float16` on CUDA: the authors autocast the UNet, weights float32
            autocast = (
                dtype == "float16"
                and dev.startswith("cuda")
                and suggested.compat == "neural-gaffer"
            )
            runtime = RuntimeConfig(device=dev, dtype=dtype, autocast=autocast)  # type: ignore[arg-type]
            pipe = RelightPipeline(net, runtime)
        return (GafferModel(pipe=pipe, name=label, source=Path(folder), suggested=suggested),)


def _photo_inputs(required_image: str) -> dict[str, Any]:
    """The inputs Relight and Turntable share (ComfyUI INPUT_TYPES entries)."""
    return {
        "model": (GAFFER_MODEL,),
        required_image: ("IMAGE", {"tooltip": "the object's photo"}),
        "envmap": (GAFFER_ENVMAP,),
        "mask_sense": (
            list(MASK_SENSES),
            {
                "default": "black = object (LoadImage)",
                "tooltip": "how `mask` marks the object: LoadImage's MASK is 1 - alpha (the object "
                "black); segmentation nodes give the object white. The MASK output uses the same sense",
            },
        ),
        "azimuth": (
            "FLOAT",
            {
                "default": 0.0,
                "min": -360.0,
                "max": 360.0,
                "step": 1.0,
                "tooltip": "orbit camera azimuth, degrees counter-clockwise from world +x (ignored "
                "when `w2c` is given)",
            },
        ),
        "elevation": (
            "FLOAT",
            {
                "default": 0.0,
                "min": -90.0,
                "max": 90.0,
                "step": 1.0,
                "tooltip": "orbit camera elevation, degrees (ignored when `w2c` is given)",
            },
        ),
        "seed": ("INT", {"default": 0, "min": 0, "max": 2**63 - 1}),
        "steps": (
            "INT",
            {"default": 0, "min": 0, "max": 1000, "tooltip": "denoising steps; 0: the model's own"},
        ),
        "guidance": (
            "FLOAT",
            {
                "default": -1.0,
                "min": -1.0,
                "max": 100.0,
                "step": 0.1,
                "tooltip": "classifier-free guidance scale; negative: the model's own",
            },
        ),
        "output_size": (
            list(OUTPUT_SIZES),
            {"default": "input", "tooltip": "input: the photo's size; model: the model's crop"},
        ),
        "detail": (
            list(DETAIL_MODES),
            {
                "default": "transfer",
                "tooltip": "transfer: the model's change of shading applied to the full-size photo; "
                "resize: its output upsampled",
            },
        ),
        "background": (
            list(BACKGROUNDS),
            {
                "default": "input",
                "tooltip": "around the object: the photo's pixels, or the target map as the camera "
                "sees it",
            },
        ),
    }


_OPTIONAL = {
    "mask": (
        "MASK",
        {
            "tooltip": "the object's mask, in `mask_sense`; without it: the IMAGE's alpha, "
            "else a GrabCut estimate"
        },
    ),
    "w2c": (
        "STRING",
        {
            "default": "",
            "tooltip": "a Blender world-to-camera matrix (12 or 16 numbers, row by row, or a .npy "
            "path); when given, `azimuth`/`elevation` are ignored",
        },
    ),
}


def _job(node: str, frames: int, **kw: Any) -> RelightJob:
    model = check_model(node, kw["model"])
    return RelightJob(
        model=model,
        envmap=check_envmap(node, kw["envmap"]),
        pose=camera_pose(node, kw["azimuth"], kw["elevation"], kw.get("w2c") or ""),
        frames=frames,
        seed=kw["seed"],
        sampling=sampling_for(node, model, kw["steps"], kw["guidance"], kw["seed"]),
        output_size=check_choice(node, "output_size", kw["output_size"], OUTPUT_SIZES),
        detail=check_choice(node, "detail", kw["detail"], DETAIL_MODES),
        background=check_choice(node, "background", kw["background"], BACKGROUNDS),
    )


class NeuralGafferRelight:
    """Relight the object of a photo under an HDR environment map (Neural Gaffer)."""

    CATEGORY = CATEGORY
    FUNCTION = "relight"
    RETURN_TYPES = ("IMAGE", "MASK")
    RETURN_NAMES = ("image", "mask")
    DESCRIPTION = (
        "The photo with its object relit under `envmap` seen from the camera (azimuth/elevation or "
        "w2c), at the photo's size (or the model's crop); the MASK is the object mask used, in "
        "`mask_sense`. Same pixels as `gaffer-diffusion relight`."
    )

    @classmethod
    def INPUT_TYPES(cls) -> dict[str, Any]:
        return {"required": _photo_inputs("image"), "optional": dict(_OPTIONAL)}

    def relight(
        self,
        model: GafferModel,
        image: Any,
        envmap: Any,
        mask_sense: str,
        azimuth: float,
        elevation: float,
        seed: int,
        steps: int,
        guidance: float,
        output_size: str,
        detail: str,
        background: str,
        mask: Any = None,
        w2c: str = "",
    ) -> tuple[Any, Any]:
        node = "NeuralGafferRelight"
        job = _job(
            node, 1, model=model, envmap=envmap, azimuth=azimuth, elevation=elevation, w2c=w2c,
            seed=seed, steps=steps, guidance=guidance, output_size=output_size, detail=detail,
            background=background,
        )  # fmt: skip
        img = check_image(node, "image", image)
        items = photo_items(node, img, object_alphas(node, img, mask, mask_sense), "image")
        progress = Progress(len(items))
        relit = [relight_item(node, job, item, progress) for item in items]
        return (
            to_image([r.frames[0] for r in relit]),
            to_mask([r.alpha for r in relit], mask_sense),
        )


class NeuralGafferTurntable:
    """Spin the light about world up around a relit object: an IMAGE batch of `frames` frames."""

    CATEGORY = CATEGORY
    FUNCTION = "turntable"
    RETURN_TYPES = ("IMAGE",)
    RETURN_NAMES = ("frames",)
    DESCRIPTION = (
        "Frame k relights the photo under `envmap` turned by k 360/frames degrees about world up, one "
        "seed for all frames (less flicker), as `gaffer-diffusion relight --turntable N`. Feed the "
        "batch to a video or GIF node."
    )

    @classmethod
    def INPUT_TYPES(cls) -> dict[str, Any]:
        required = _photo_inputs("image")
        required["frames"] = ("INT", {"default": 24, "min": 2, "max": 360})
        return {"required": required, "optional": dict(_OPTIONAL)}

    def turntable(
        self,
        model: GafferModel,
        image: Any,
        envmap: Any,
        mask_sense: str,
        azimuth: float,
        elevation: float,
        seed: int,
        steps: int,
        guidance: float,
        output_size: str,
        detail: str,
        background: str,
        frames: int,
        mask: Any = None,
        w2c: str = "",
    ) -> tuple[Any]:
        node = "NeuralGafferTurntable"
        if isinstance(frames, bool) or not isinstance(frames, int) or not 2 <= frames <= 360:
            raise NodeInputError(f"{node}: `frames` is {frames!r}; pass an integer in [2, 360].")
        job = _job(
            node, frames, model=model, envmap=envmap, azimuth=azimuth, elevation=elevation,
            w2c=w2c, seed=seed, steps=steps, guidance=guidance, output_size=output_size,
            detail=detail, background=background,
        )  # fmt: skip
        img = check_image(node, "image", image)
        if img.shape[0] != 1:
            raise NodeInputError(
                f"{node}: `image` holds {img.shape[0]} pictures; the turntable spins one: pick it "
                "with an ImageFromBatch node."
            )
        items = photo_items(node, img, object_alphas(node, img, mask, mask_sense), "image")
        relit = relight_item(node, job, items[0], Progress(frames))
        return (to_image(relit.frames),)
