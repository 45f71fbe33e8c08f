"""Command line: `gaffer-diffusion demo | relight | evaluate | init-random | train`.

    gaffer-diffusion demo --out DIR [--checkpoint CKPT] [--steps N] [--frames 24]
        (README's main job: the shipped example object relit under the bundled HDRIs and a turntable;
        PNGs, a GIF, metrics.json and report.html)
    gaffer-diffusion relight IMAGE --envmap ENV.exr (--w2c W2C.npy | --azimuth DEG --elevation DEG)
        [--checkpoint CKPT] [--base-model DIR] --out OUT.png [--steps N] [--guidance S] [--seed 0]
        [--turntable N]
    gaffer-diffusion relight IMAGE --ldr LDR.png --hdr HDR.png --checkpoint CKPT ... (pre-encoded maps)
    gaffer-diffusion relight IMAGES_DIR --envmaps ENVMAPS_DIR (--w2c | --azimuth --elevation)
        --checkpoint CKPT --out OUT_DIR   (every image x every map, batched; OUT_DIR/<image>/<map>.png)
    gaffer-diffusion evaluate --dataset DIR --checkpoint CKPT [--base-model DIR] [--envmaps DIR]
        [--steps 50] [--limit N] [--json F] [--markdown F]   (a gaffer-data rendered dataset)
    gaffer-diffusion evaluate --pred DIR --gt DIR [--mask-dir DIR] [--lpips-backbone FILE] [--json F]
    gaffer-diffusion prepare IMAGE --out OUT.png [--mask M] [--compat neural-gaffer|default]
        (the model-ready square input on white and OUT_mask.png)
    gaffer-diffusion check --checkpoint DIR --base-model DIR   (validate the authors' release first)
    gaffer-diffusion init-random --preset tiny --out DIR   (random weights in our format, for demos)
    gaffer-diffusion train --config CONFIG.json [--resume]   (extra [train]; configs/ has examples)
    gaffer-diffusion app [--host 127.0.0.1] [--port 7860] [--model DIR]   (extra [app]: the browser app)

`--checkpoint` is either our format (a folder with `gaffer_model.json`) or the authors' release
(`checkpoint-80000/`), which also needs `--base-model` (a local Zero-1-to-3 XL diffusers folder).
Without `--checkpoint`, `relight` and `demo` use gaffer-tiny, the 128 px model shipped in the package.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, get_args

# Only torch-free modules at import time: every argument is checked before torch, diffusers or a
# model loads, so a refusal takes well under a second (issue 17); the rest is imported where used.
from gaffer_diffusion import _cli_checks as checks
from gaffer_diffusion import pretrained
from gaffer_diffusion._choices import (
    BACKDROP_FOV_DEG,
    MANIFEST_NAME,
    PRESETS,
    SCHEDULERS,
    Background,
    DetailMode,
    LatentMode,
    OutputSize,
    PrepareCompat,
)
from gaffer_diffusion.app.config import add_app_arguments
from gaffer_diffusion.errors import (
    ConfigError,
    GafferDiffusionError,
    InputValueError,
    MissingDependencyError,
)
from gaffer_diffusion.suggested import SuggestedSampling, read_suggested_sampling
from gaffer_envmap.errors import GafferError

if TYPE_CHECKING:
    import numpy as np
    import torch
    from tqdm import tqdm

    from gaffer_diffusion.conditioning import LightingMaps
    from gaffer_diffusion.models.model import NeuralGafferModel
    from gaffer_diffusion.photo import Photo, PreparedPhoto
    from gaffer_diffusion.pipelines import RuntimeConfig, SamplingConfig

logger = logging.getLogger(__name__)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="gaffer-diffusion", description=(__doc__ or "").split("\n\n")[0]
    )
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("relight", help="relight one object image under an environment map")
    r.add_argument(
        "image", type=Path, help="object image (RGBA, or RGB with --mask), or a folder of them"
    )
    r.add_argument(
        "--mask",
        type=_mask_arg,
        help="object mask (white = object) for images without alpha; a folder of masks with the "
        "images' file names when IMAGE is a folder; 'auto': a classical GrabCut estimate (offline, "
        "no weights), written beside the output as OUT.mask.png",
    )
    r.add_argument(
        "--sam-checkpoint",
        type=Path,
        help="a local Segment Anything checkpoint (needs `pip install segment-anything`) for the mask",
    )
    r.add_argument(
        "--output-size",
        choices=get_args(OutputSize),
        default="input",
        help="'input' (default): the photo at its own size, the relit object pasted back at its place; "
        "'model': the model's square crop",
    )
    r.add_argument(
        "--detail",
        choices=get_args(DetailMode),
        default="transfer",
        help="how the model's result reaches full size: 'transfer' (default) applies its change of "
        "shading to the full-resolution photo; 'resize' upsamples it bicubically",
    )
    r.add_argument(
        "--background",
        choices=get_args(Background),
        default="input",
        help="around the object: the photo's own pixels ('input', default) or the target environment "
        "as the camera sees it ('envmap', needs --envmap)",
    )
    r.add_argument(
        "--fov",
        type=float,
        default=BACKDROP_FOV_DEG,
        help="horizontal field of view of the --background envmap camera, degrees",
    )
    light = r.add_argument_group("lighting: --envmap with a pose, or pre-encoded --ldr/--hdr maps")
    light.add_argument(
        "--envmap",
        type=_envmap_path,
        help="equirectangular HDR map (.exr/.hdr), Blender z-up, or the name of a bundled CC0 HDRI "
        "(city, courtyard, forest, interior, night, studio, sunrise, sunset)",
    )
    light.add_argument(
        "--envmaps",
        type=Path,
        help="a folder of .exr/.hdr maps: relight under each of them (OUT is then a folder)",
    )
    light.add_argument("--w2c", type=Path, help="3x4 or 4x4 Blender world-to-camera .npy")
    light.add_argument("--azimuth", type=float, help="orbit camera azimuth, degrees")
    light.add_argument("--elevation", type=float, help="orbit camera elevation, degrees")
    light.add_argument("--ldr", type=Path, help="pre-encoded camera-frame LDR map (PNG)")
    light.add_argument("--hdr", type=Path, help="pre-encoded camera-frame HDR map (PNG)")
    light.add_argument(
        "--compat",
        choices=("neural-gaffer", "default"),
        default=None,
        help="lighting encoding; 'neural-gaffer' matches the released checkpoint (the default with "
        "--checkpoint); without one, gaffer-tiny's own ('default')",
    )
    light.add_argument(
        "--sanitize",
        choices=("zero", "clamp", "raise"),
        default="zero",
        help="NaN/Inf/negative env-map pixels: set to 0 (default), clamp, or fail",
    )
    r.add_argument(
        "--checkpoint",
        type=Path,
        help="our model folder or checkpoint-80000/ (default: gaffer-tiny, shipped, 128 px)",
    )
    r.add_argument(
        "--base-model", type=Path, help="Zero-1-to-3 XL folder (authors' checkpoint only)"
    )
    r.add_argument(
        "--out",
        type=Path,
        required=True,
        help="output PNG (turntable: frame prefix + GIF/MP4; folder of images or --envmaps: a folder)",
    )
    r.add_argument(
        "--turntable", type=int, default=0, help="N frames of the light spinning about up"
    )
    r.add_argument(
        "--video",
        choices=("auto", "gif", "mp4"),
        default="auto",
        help="turntable animation: mp4 needs ffmpeg on PATH or PyAV; auto falls back to gif",
    )
    r.add_argument("--fps", type=float, default=12.0, help="turntable frames per second")
    _add_sampling_args(r)

    e = sub.add_parser(
        "evaluate",
        help="relight a rendered dataset with a model and score it (--dataset), or score "
        "predicted images against ground truth matched by name (--pred/--gt)",
    )
    ds = e.add_argument_group("a model on a gaffer-data rendered dataset")
    ds.add_argument(
        "--dataset", type=Path, help="gaffer-data render folder (gaffer-data render --out)"
    )
    ds.add_argument(
        "--checkpoint",
        type=Path,
        help="our model folder or checkpoint-80000/ (default: the shipped gaffer-tiny)",
    )
    ds.add_argument("--base-model", type=Path, help="Zero-1-to-3 XL folder (authors' checkpoint)")
    ds.add_argument(
        "--envmaps", type=Path, help="where the dataset's env maps are now, if they moved"
    )
    ds.add_argument(
        "--input-lighting",
        type=_input_lighting,
        default=0,
        help="lighting index of each view's input render, or 'area' (default 0)",
    )
    ds.add_argument("--limit", type=int, help="evaluate only the first N pairs")
    ds.add_argument("--save-predictions", type=Path, help="write every prediction PNG here")
    ds.add_argument(
        "--compat",
        choices=("neural-gaffer", "default"),
        default=None,
        help="lighting encoding (default: 'neural-gaffer' for a --checkpoint, gaffer-tiny's own "
        "'default' without one)",
    )
    ds.add_argument(
        "--object-fraction",
        type=float,
        default=None,
        help="crop each view around its object, which then spans this fraction of the side "
        "(default: the whole render for a --checkpoint; gaffer-tiny: 0.75, as it was trained)",
    )
    _add_sampling_args(ds)
    fo = e.add_argument_group("two folders of images")
    fo.add_argument("--pred", type=Path, help="predicted images")
    fo.add_argument("--gt", type=Path, help="ground-truth images with the same file names")
    fo.add_argument(
        "--mask-dir", type=Path, help="masks with the same file names (channel alignment)"
    )
    e.add_argument(
        "--lpips-backbone", type=Path, help="torchvision AlexNet weights for standard LPIPS"
    )
    e.add_argument(
        "--no-perceptual", action="store_true", help="skip the perceptual metric (faster)"
    )
    e.add_argument("--json", type=Path, help="write the full report as JSON")
    e.add_argument("--markdown", type=Path, help="write the table of means as markdown")

    d = sub.add_parser(
        "demo",
        help="relight the shipped example object under the bundled HDRIs and a turntable; write "
        "PNGs, a GIF, metrics.json and report.html",
    )
    d.add_argument("--out", type=Path, required=True, help="output folder (created if missing)")
    d.add_argument(
        "--checkpoint", type=Path, help="our model folder (default: gaffer-tiny, shipped)"
    )
    d.add_argument(
        "--example", type=Path, help="a gaffer-data render folder (default: the shipped example)"
    )
    d.add_argument(
        "--steps", type=int, help="denoising steps (default: the model's suggestion, else 50)"
    )
    d.add_argument(
        "--guidance", type=float, help="CFG scale (default: the model's suggestion, else 3)"
    )
    d.add_argument(
        "--average-samples",
        type=int,
        default=None,
        help="mean of K samples per image (default: the model's suggestion, else 1)",
    )
    d.add_argument(
        "--mirror-average",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="average with the input mirrored left-right under the mirrored lighting (2x the cost; "
        "default: off, gaffer-tiny: its model card's setting)",
    )
    d.add_argument("--frames", type=int, default=24, help="turntable frames (0: none)")
    d.add_argument(
        "--turntable-hdri",
        default=None,
        help="bundled HDRI the turntable spins (default: the one whose light changes most with the spin)",
    )
    d.add_argument("--fps", type=float, default=12.0, help="turntable GIF frames per second")
    d.add_argument("--seed", type=int, default=0, help="sampling seed (0)")
    d.add_argument("--batch-size", type=int, default=8, help="images per sampling call")
    d.add_argument(
        "--device",
        default=None,
        help="torch device (default: cuda when available, else cpu)",
    )
    d.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch CPU threads (default 1: the small model gains little from more, and on a busy "
        "2-core machine 2 OpenMP threads ran 20x slower than 1)",
    )
    d.add_argument(
        "--full-frame",
        action="store_true",
        help="keep the model's whole output; by default the input's background (outside its "
        "alpha/mask) is kept, as the view does not move",
    )
    d.add_argument(
        "--compat",
        choices=("neural-gaffer", "default"),
        default=None,
        help="lighting encoding (default: the model's own; gaffer-tiny: 'default')",
    )
    d.add_argument(
        "--object-fraction",
        type=float,
        default=None,
        help="crop the example around its object, which then spans this fraction of the side "
        "(default: the model's framing; gaffer-tiny: 0.75)",
    )
    d.add_argument(
        "--no-extra-hdris",
        action="store_true",
        help="skip the bundled HDRIs that have no ground-truth render",
    )

    _add_authors_commands(sub)

    i = sub.add_parser(
        "init-random", help="save a random-weight model in our format (demos, tests)"
    )
    i.add_argument(
        "--preset", choices=PRESETS, default="tiny", help="model shapes to build (default: tiny)"
    )
    i.add_argument("--seed", type=int, default=0, help="seed of the random weights (0)")
    i.add_argument("--out", type=Path, required=True, help="model folder to write")

    x = sub.add_parser(
        "export",
        help="write a training checkpoint (its EMA weights) as a model folder for evaluate/relight",
    )
    x.add_argument("checkpoint", type=Path, help="a checkpoint-NNNNNNNN/ folder of a training run")
    x.add_argument("--out", type=Path, required=True, help="destination model folder")
    x.add_argument("--raw", action="store_true", help="the trained weights instead of the EMA")

    add_app_arguments(
        sub.add_parser(
            "app", help="relight a photo in the browser (extra [app], Gradio; 127.0.0.1)"
        )
    )

    t = sub.add_parser("train", help="train the UNet on gaffer-data renders (extra [train])")
    t.add_argument("--config", type=Path, required=True, help="training config JSON (see configs/)")
    t.add_argument(
        "--resume", action="store_true", help="continue from the newest checkpoint in output_dir"
    )
    return p


def _add_sampling_args(p: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    p.add_argument(
        "--steps", type=int, help="denoising steps (default: 50, the paper's; gaffer-tiny: 1)"
    )
    p.add_argument(
        "--guidance", type=float, help="CFG scale (default: 3, the paper's; gaffer-tiny: 1)"
    )
    p.add_argument("--seed", type=int, default=0, help="sampling seed: item i uses seed + i (0)")
    p.add_argument(
        "--scheduler",
        choices=SCHEDULERS,
        default="ddim",
        help="sampler (default: ddim, the paper's)",
    )
    p.add_argument(
        "--average-samples",
        type=int,
        default=None,
        help="mean of K samples per output (a posterior-mean estimate: best PSNR, K times the cost; "
        "default 1, gaffer-tiny: its model card's setting)",
    )
    p.add_argument(
        "--mirror-average",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="average with the input mirrored left-right under the mirrored lighting (2x the cost; "
        "default: off, gaffer-tiny: its model card's setting)",
    )
    p.add_argument("--batch-size", type=int, default=4, help="images per sampling call")
    p.add_argument(
        "--device",
        default=None,
        help="torch device (default: cuda when available, else cpu)",
    )
    p.add_argument(
        "--dtype",
        choices=("float32", "float16", "bfloat16"),
        default="float32",
        help="weights' precision (default: float32)",
    )
    p.add_argument(
        "--autocast",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="keep float32 weights and run the UNet under torch.autocast in --dtype (default: on "
        "for --dtype float16 on CUDA with --compat neural-gaffer, as the authors run it)",
    )
    p.add_argument(
        "--latent-mode",
        choices=get_args(LatentMode),
        default=None,
        help="conditioning latents: a posterior 'sample' seeded per item (the authors'; default "
        "with --compat neural-gaffer) or the posterior 'mode' (deterministic; default otherwise)",
    )
    p.add_argument(
        "--full-frame",
        action="store_true",
        help="keep the model's whole output; by default the input's background (outside its "
        "alpha/mask) is kept, as the view does not move",
    )


def _input_lighting(text: str) -> int | str:
    if text == "area":
        return text
    try:
        return int(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(
            f"{text!r} is neither a lighting index nor 'area'"
        ) from exc


def _load_model(checkpoint: Path | None, base_model: Path | None) -> NeuralGafferModel:
    from gaffer_diffusion.loading import load_authors_release, load_pretrained

    if checkpoint is None:
        from gaffer_diffusion.demo import load_model

        if base_model is not None:
            raise ConfigError("`--base-model` goes with the authors' `--checkpoint`; pass both.")
        return load_model(None).model  # logs that (and where from) it uses gaffer-tiny
    if (checkpoint / MANIFEST_NAME).is_file():
        return load_pretrained(checkpoint).model
    if base_model is None:
        raise _base_model_error(checkpoint)
    result = load_authors_release(checkpoint, base_model)
    logger.info("%s", result.report.summary())
    return result.model


def _check_checkpoint_args(checkpoint: Path | None, base_model: Path | None) -> None:
    """The checkpoint flags' consistency, checked before any input is read or weight loaded."""
    if checkpoint is None or (checkpoint / MANIFEST_NAME).is_file() or base_model is not None:
        return
    raise _base_model_error(checkpoint)


def _base_model_error(checkpoint: Path) -> ConfigError:
    return ConfigError(
        f"`--checkpoint` {checkpoint} is not a gaffer-diffusion model folder (no {MANIFEST_NAME}), so "
        "it is taken as the authors' release, which needs `--base-model DIR` (a local Zero-1-to-3 XL "
        "diffusers folder with vae/, image_encoder/, scheduler/, unet/config.json)."
    )


def _pose(args: argparse.Namespace) -> Any:
    """The camera of `--w2c` or `--azimuth/--elevation`; numpy and gaffer-envmap only (no torch), so
    the checks call it before any weights load."""
    from gaffer_envmap.poses import W2CBlender, orbit_w2c_blender

    if args.w2c is not None:
        if args.azimuth is not None or args.elevation is not None:
            raise ConfigError("Pass either `--w2c` or `--azimuth`/`--elevation`, not both.")
        return W2CBlender.from_array(_read_w2c(args.w2c))
    if args.azimuth is not None and args.elevation is not None:
        checks.finite("--azimuth", args.azimuth)
        checks.finite("--elevation", args.elevation, -90.0, 90.0)
        return orbit_w2c_blender(args.azimuth, args.elevation)
    raise ConfigError("Give the camera: `--w2c W2C.npy`, or both `--azimuth` and `--elevation`.")


def _read_w2c(path: Path) -> np.ndarray:
    """`--w2c`: a 3x4 or 4x4 float .npy (no pickles), refused with one line otherwise."""
    import numpy as np

    checks.need_file("--w2c", path, "a 3x4 or 4x4 world-to-camera .npy (numpy.save)")
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise InputValueError(
            f"`--w2c` {path} is not a plain numeric .npy ({exc}); save the 3x4 or 4x4 matrix with "
            "numpy.save (no pickled objects)."
        ) from exc
    if (
        not isinstance(arr, np.ndarray)
        or arr.dtype.kind not in "fiu"
        or arr.shape not in ((3, 4), (4, 4))
    ):
        shape = getattr(arr, "shape", None)
        raise InputValueError(
            f"`--w2c` {path} holds {getattr(arr, 'dtype', type(arr).__name__)} of shape {shape}; "
            "pass a 3x4 or 4x4 float world-to-camera matrix."
        )
    if not np.isfinite(arr).all():
        raise InputValueError(f"`--w2c` {path} holds NaN or Inf; pass a finite matrix.")
    return arr.astype(np.float64)


def _envmap_lighting(
    args: argparse.Namespace, envmap: Path, size: int, frames: int = 0
) -> LightingMaps:
    import torch

    from gaffer_diffusion.conditioning import lighting_from_envmap
    from gaffer_envmap.io import read_envmap

    pose = _pose(args)
    env = read_envmap(envmap, sanitize=args.sanitize)
    n = max(frames, 1)
    spin = torch.arange(n, dtype=torch.float64) * (360.0 / n) if frames > 1 else 0.0
    return lighting_from_envmap(env, [pose] * n, size=size, compat=_compat(args), spin_deg=spin)


def _suggestion(args: argparse.Namespace) -> SuggestedSampling:
    """The model's own sampling (`gaffer_diffusion.suggested`): the shipped gaffer-tiny's without
    `--checkpoint`, else what the model folder records (the paper's for the authors' release or a
    folder that records none). A JSON read, no torch."""
    checkpoint = getattr(args, "checkpoint", None)
    return read_suggested_sampling(
        pretrained.gaffer_tiny_path() if checkpoint is None else Path(checkpoint).expanduser()
    )


def _compat(args: argparse.Namespace) -> Any:
    """`--compat`, else the lighting encoding the model was trained with (`_suggestion`)."""
    if args.compat is not None:
        return args.compat
    return _suggestion(args).compat


def _lighting(args: argparse.Namespace, size: int, frames: int) -> LightingMaps:
    if args.ldr is not None or args.hdr is not None:
        if args.ldr is None or args.hdr is None or args.envmap is not None:
            raise ConfigError("Pass both `--ldr` and `--hdr` (pre-encoded maps) and no `--envmap`.")
        if frames > 1:
            raise ConfigError("`--turntable` needs `--envmap` (pre-encoded maps cannot be spun).")
        from gaffer_diffusion.conditioning import LightingMaps
        from gaffer_diffusion.evaluation import read_lighting_map

        return LightingMaps(
            ldr=read_lighting_map(args.ldr, size), hdr=read_lighting_map(args.hdr, size)
        )
    if args.envmap is None:
        raise ConfigError(
            "Pass `--envmap ENV.exr` (or `--envmaps DIR`) with a pose, or pre-encoded `--ldr` and "
            "`--hdr` maps."
        )
    return _envmap_lighting(args, args.envmap, size, frames)


def _save_png(path: Path, image: torch.Tensor | np.ndarray) -> None:
    """Write a PNG atomically: the file is complete or absent (`gaffer_envmap.atomic`)."""
    import numpy as np
    from PIL import Image

    from gaffer_envmap.atomic import atomic_path

    arr = image if isinstance(image, np.ndarray) else _to_uint8(image)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        Image.fromarray(arr).save(tmp, format="PNG")


def _to_uint8(image: torch.Tensor) -> np.ndarray:
    import numpy as np

    return (image.clamp(0, 1).permute(1, 2, 0).cpu().numpy() * 255.0).round().astype(np.uint8)


def _progress(total: int, desc: str) -> tqdm[Any]:
    from tqdm.auto import tqdm

    return tqdm(total=total, desc=desc, unit="img", file=sys.stderr)


def _sampling(args: argparse.Namespace) -> SamplingConfig:
    from gaffer_diffusion.pipelines import SamplingConfig

    # every value the user leaves out is the model's own (its folder's `suggested_sampling`)
    suggested = _suggestion(args)

    def pick(given: Any, own: Any) -> Any:
        return own if given is None else given

    # an explicit 0 is refused by SamplingConfig (it used to mean "the default" silently)
    return SamplingConfig(
        num_inference_steps=pick(args.steps, suggested.num_inference_steps),
        guidance_scale=pick(args.guidance, suggested.guidance_scale),
        scheduler=args.scheduler,
        average_samples=pick(args.average_samples, suggested.average_samples),
        mirror_average=bool(pick(args.mirror_average, suggested.mirror_average)),
        latent_mode=_latent_mode(args),
    )


def _latent_mode(args: argparse.Namespace) -> Any:
    """`--latent-mode`, else the authors' posterior sample under `--compat neural-gaffer` (issue 15)."""
    if args.latent_mode is not None:
        return args.latent_mode
    return "sample" if _compat(args) == "neural-gaffer" else "mode"


def _runtime(args: argparse.Namespace) -> RuntimeConfig:
    """Device and precision; `--dtype float16` on CUDA under `--compat neural-gaffer` autocasts the
    UNet with float32 weights, as the authors run it (official implementation §2)."""
    from gaffer_diffusion.pipelines import RuntimeConfig

    _check_autocast(args)
    device = _device(args, check=False)  # checked before the weights load (_load_model callers)
    autocast = args.autocast
    if autocast is None:
        autocast = (
            args.dtype == "float16"
            and device.startswith("cuda")
            and _compat(args) == "neural-gaffer"
        )
    return RuntimeConfig(device=device, dtype=args.dtype, autocast=bool(autocast))


def _check_autocast(args: argparse.Namespace) -> None:
    if args.autocast and args.dtype == "float32":
        raise ConfigError(
            "`--autocast` runs the UNet in lower precision: add `--dtype float16` (the authors') or "
            "`--dtype bfloat16`."
        )


def _device(args: argparse.Namespace, *, check: bool = True) -> str:
    """`--device`, else cuda when available; with `check`, a CUDA device this torch cannot use is
    refused."""
    import torch

    if args.device is None:
        return "cuda" if torch.cuda.is_available() else "cpu"
    device = str(args.device)
    if not check:
        return device
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise ConfigError(
            f"`--device {device}`: this torch build ({torch.__version__}) sees no CUDA GPU; pass "
            "`--device cpu`, or install a CUDA build of torch on a machine with a GPU."
        )
    if device.startswith("mps") and not torch.backends.mps.is_available():
        raise ConfigError(f"`--device {device}`: no Apple MPS device here; pass `--device cpu`.")
    return device


def _background_note(args: argparse.Namespace) -> str:
    """The background choice, named in every relight report (issue 15, reading 5)."""
    if getattr(args, "background", "input") == "envmap":
        return "background: the target environment as the camera sees it (--background envmap)"
    if args.full_frame:
        return "background: the model's full frame (--full-frame, the authors' protocol)"
    return (
        "background: the input's, kept outside its alpha (--full-frame for the authors' full frame)"
    )


def _mask_arg(text: str) -> Path | str:
    """`--mask`: a path, or 'auto' (GrabCut)."""
    return "auto" if text == "auto" else Path(text)


def _mask_out(out: Path) -> Path:
    """Where an automatic mask is written: beside the output, `OUT.mask.png`."""
    return out.with_name(f"{out.with_suffix('').name}.mask.png")


def _check_photo_flags(args: argparse.Namespace) -> None:
    """`--mask auto` / `--sam-checkpoint` / `--background` refused early, before any input is read."""
    sam = getattr(args, "sam_checkpoint", None)
    if sam is not None:
        if args.mask is not None:
            raise ConfigError("Pass `--mask` or `--sam-checkpoint`, not both.")
        import importlib.util

        if importlib.util.find_spec("segment_anything") is None:
            raise MissingDependencyError(
                "`--sam-checkpoint` needs segment-anything, which is not installed: "
                "pip install segment-anything (or use `--mask auto`, the classical GrabCut fallback)."
            )
    if args.mask == "auto":
        from gaffer_diffusion.automask import require_opencv

        require_opencv()
    if getattr(args, "background", "input") == "envmap":
        if args.envmap is None and getattr(args, "envmaps", None) is None:
            raise ConfigError(
                "`--background envmap` shows the target environment: pass it with `--envmap ENV.exr` "
                "(pre-encoded `--ldr/--hdr` maps cannot be shown)."
            )
        if not 1.0 <= args.fov < 180.0:
            raise ConfigError(f"`--fov` is {args.fov}; expected degrees in [1, 180).")


def _photo_and_mask(
    args: argparse.Namespace, image: Path, mask: Path | str | None, mask_out: Path
) -> tuple[Photo, np.ndarray, str]:
    """The photo and its object mask, read and checked before any weights load, and a note on the mask
    for the report (an automatic mask is written to `mask_out`)."""
    import numpy as np

    from gaffer_diffusion.photo import object_alpha, read_mask, read_photo

    photo = read_photo(image)
    sam = getattr(args, "sam_checkpoint", None)
    if sam is None and mask != "auto":
        m = read_mask(mask, photo) if isinstance(mask, Path) else None
        return photo, object_alpha(photo, m), ""
    from gaffer_diffusion import automask
    from gaffer_diffusion.photo import check_mask

    if sam is not None:
        alpha, how = automask.sam_mask(photo.rgb_u8, sam), f"Segment Anything ({sam.name})"
    else:
        alpha = automask.grabcut_mask(photo.rgb_u8)
        how = "--mask auto, GrabCut: a classical fallback, not a learned segmenter"
    check_mask(alpha, f"The automatic mask of `{image}`")
    _save_png(mask_out, np.round(np.clip(alpha, 0, 1) * 255).astype(np.uint8))
    note = (
        f"mask ({how}) written to {mask_out}: check it, and pass a corrected one with "
        f"`--mask {mask_out}`"
    )
    return photo, alpha, note


def _backdrop(
    args: argparse.Namespace,
    envmap: Path | None,
    height: int,
    width: int,
    fov: float,
    k: int,
    n: int,
) -> np.ndarray | None:
    """The target environment as the camera sees it (`--background envmap`), or None."""
    if args.background == "input" or envmap is None:
        return None
    from gaffer_diffusion.photo import envmap_backdrop
    from gaffer_envmap.io import read_envmap

    env = read_envmap(envmap, sanitize=args.sanitize)
    return envmap_backdrop(
        env.radiance_linear,
        _pose(args).rotation,
        height=height,
        width=width,
        convention=env.convention,
        fov_deg=fov,
        spin_deg=k * 360.0 / n if n > 1 else 0.0,
    )


def _finish(
    args: argparse.Namespace,
    prepared: PreparedPhoto,
    relit: torch.Tensor,
    envmap: Path | None,
    frame: tuple[int, int] = (0, 1),
) -> np.ndarray:
    """One model result as written: pasted back at the photo's size, or the model's crop."""
    import numpy as np

    from gaffer_diffusion.photo import model_crop, paste_back

    k, n = frame
    match args.output_size:
        case "model":
            s = int(relit.shape[-1])
            # the crop sees a narrower field than the photo: its share of the photo's width
            share = prepared.framing.side_x / prepared.photo.size_wh[0]
            fov = float(np.rad2deg(2 * np.arctan(np.tan(np.deg2rad(args.fov) / 2) * share)))
            bd = _backdrop(args, envmap, s, s, min(fov, 179.0), k, n)
            if bd is None:
                return model_crop(relit)
            m = prepared.model_input.mask[0, 0].numpy()[..., None]
            rgb = relit.clamp(0, 1).permute(1, 2, 0).numpy()
            return np.round((m * rgb + (1 - m) * bd) * 255).astype(np.uint8)
        case "input":
            h, w = prepared.alpha.shape
            bd = _backdrop(args, envmap, h, w, args.fov, k, n)
            return paste_back(prepared, relit, detail=args.detail, backdrop=bd)
        case _:
            raise ConfigError(f"`--output-size` is {args.output_size!r}; expected input or model.")


# --- cheap checks: every flag of a command, before torch is imported or a model loaded (issue 17) ---

_DEVICE_NAMES = ("cpu", "cuda", "mps", "xpu")


def _check_device_cheaply(device: str | None) -> None:
    """`--device` names a torch device, and a CUDA one has a GPU to run on (no torch import: a
    Linux machine without /dev/nvidia* has no CUDA device; torch confirms it later)."""
    if device is None:
        return
    kind, _, index = device.partition(":")
    if kind not in _DEVICE_NAMES or (index and not index.isdigit()):
        raise ConfigError(f"`--device` is {device!r}; expected cpu, cuda, cuda:N or mps.")
    if kind == "cuda" and sys.platform.startswith("linux"):
        if not any(Path("/dev").glob("nvidia[0-9]*")):
            raise ConfigError(
                f"`--device {device}`: this machine has no NVIDIA GPU (no /dev/nvidia*); pass "
                "`--device cpu`."
            )


def _check_sampling_args(args: argparse.Namespace) -> None:
    checks.int_range("--steps", args.steps, 1, checks.MAX_STEPS, "gaffer-tiny: 1, the paper: 50")
    checks.finite("--guidance", args.guidance, 0.0, 100.0)
    checks.int_range("--average-samples", args.average_samples, 1, checks.MAX_AVERAGE_SAMPLES)
    checks.int_range("--batch-size", args.batch_size, 1, checks.MAX_BATCH)
    checks.int_range("--seed", args.seed, 0, checks.MAX_SEED)
    _check_device_cheaply(args.device)
    if hasattr(args, "autocast"):
        _check_autocast(args)


def _check_model_args(args: argparse.Namespace) -> None:
    """`--checkpoint` / `--base-model` exist and go together."""
    if args.checkpoint is not None:
        checks.need_dir(
            "--checkpoint",
            args.checkpoint,
            "a model folder (gaffer_model.json) or checkpoint-80000/",
        )
    base = getattr(args, "base_model", None)
    if base is not None:
        checks.need_dir("--base-model", base, "a local Zero-1-to-3 XL diffusers folder")
    _check_checkpoint_args(args.checkpoint, base)


def _check_envmap_arg(path: Path) -> None:
    if not path.exists() and not path.suffix:
        from gaffer_envmap.bundled import bundled_hdris

        names = ", ".join(sorted(bundled_hdris()))
        raise InputValueError(
            f"`--envmap` {path} is neither a file nor a bundled HDRI; pass an .exr/.hdr file or one "
            f"of: {names}."
        )
    checks.envmap_file("--envmap", path)


def _check_lighting_args(args: argparse.Namespace) -> None:
    if args.envmaps is not None:
        checks.need_dir("--envmaps", args.envmaps, "a folder of .exr/.hdr maps")
        for m in _files(args.envmaps, _ENVMAP_SUFFIXES, "environment maps", "--envmaps"):
            checks.envmap_file("--envmaps", m)
    elif args.ldr is not None or args.hdr is not None:
        if args.ldr is None or args.hdr is None or args.envmap is not None:
            raise ConfigError("Pass both `--ldr` and `--hdr` (pre-encoded maps) and no `--envmap`.")
        if args.turntable > 1:
            raise ConfigError("`--turntable` needs `--envmap` (pre-encoded maps cannot be spun).")
        checks.image_size("--ldr", args.ldr)
        checks.image_size("--hdr", args.hdr)
        return
    elif args.envmap is None:
        raise ConfigError(
            "Pass `--envmap ENV.exr` (or `--envmaps DIR`) with a pose, or pre-encoded `--ldr` and "
            "`--hdr` maps."
        )
    else:
        _check_envmap_arg(args.envmap)
        from gaffer_envmap.io import read_envmap

        read_envmap(args.envmap, sanitize=args.sanitize)  # decoded here too: no torch, fails early
    _pose(args)  # reads and checks --w2c, or --azimuth/--elevation (numpy only)


def _check_turntable_memory(args: argparse.Namespace, width: int, height: int) -> None:
    """`--turntable N` keeps N frames (and N lighting pairs) in memory: refuse what cannot fit."""
    side = (
        128 if args.checkpoint is None else 512
    )  # the model's resolution (512: the largest preset)
    out_px = side * side if args.output_size == "model" else width * height
    per_frame = 3 * 4 * out_px + 2 * 2 * 3 * side * side * 4  # frames + animation copies; E_L, E_H
    checks.fits_in_memory("--turntable", args.turntable * per_frame, f"{args.turntable} frames")


def _validate_relight(args: argparse.Namespace) -> None:
    checks.need_path(
        "IMAGE", args.image, "an object image (RGBA, or RGB with --mask) or a folder of them"
    )
    checks.int_range("--turntable", args.turntable, 0, checks.MAX_FRAMES, "e.g. 24")
    checks.finite("--fps", args.fps, 0.0, checks.MAX_FPS, lo_open=True)
    grid = args.image.is_dir() or args.envmaps is not None
    if grid and args.turntable:
        raise ConfigError(
            "`--turntable` spins one map around one image; it cannot be combined with a folder of "
            "images or `--envmaps DIR`. Relight the folder without `--turntable`."
        )
    if args.envmaps is not None and (args.envmap is not None or args.ldr is not None):
        raise ConfigError("Pass `--envmaps DIR` or `--envmap` / `--ldr --hdr`, not both.")
    _check_sampling_args(args)
    _check_lighting_args(args)
    if isinstance(args.mask, Path):
        checks.need_path("--mask", args.mask, "the object mask (white = object), or 'auto'")
    if args.sam_checkpoint is not None:
        checks.need_file("--sam-checkpoint", args.sam_checkpoint, "a Segment Anything checkpoint")
    _check_photo_flags(args)
    _check_model_args(args)
    if grid:
        checks.writable_dir("--out", args.out)
        return
    width, height = checks.image_size("IMAGE", args.image)
    checks.writable_file("--out", args.out)
    if args.turntable > 1:
        from gaffer_diffusion._video import mp4_encoder

        if args.video == "mp4" and mp4_encoder() is None:
            raise MissingDependencyError(
                "`--video mp4` needs an MP4 encoder: an `ffmpeg` binary on PATH or PyAV "
                '(`pip install av`). Neither is installed; use `--video gif` (or "auto").'
            )
        _check_turntable_memory(args, width, height)


def _validate_evaluate(args: argparse.Namespace) -> None:
    for flag, path in (("--json", args.json), ("--markdown", args.markdown)):
        if path is not None:
            checks.writable_file(flag, path)
    if args.no_perceptual and args.lpips_backbone is not None:
        raise ConfigError("Pass `--lpips-backbone` or `--no-perceptual`, not both.")
    if args.lpips_backbone is not None:
        checks.need_file("--lpips-backbone", args.lpips_backbone, "torchvision AlexNet weights")
    if args.dataset is None:
        for flag, path in (("--pred", args.pred), ("--gt", args.gt), ("--mask-dir", args.mask_dir)):
            if path is not None:
                checks.need_dir(flag, path, "a folder of images")
        return
    checks.need_dir("--dataset", args.dataset, "a gaffer-data render folder")
    if not (args.dataset / "dataset.json").is_file() and not (args.dataset / "objects").is_dir():
        raise InputValueError(
            f"`--dataset` {args.dataset} is not a gaffer-data dataset (no dataset.json, no "
            "objects/); pass the folder `gaffer-data render --out` wrote."
        )
    if args.envmaps is not None:
        checks.need_dir("--envmaps", args.envmaps, "the folder of the maps the dataset was lit by")
    checks.int_range("--limit", args.limit, 1, 2**31, "pairs to evaluate")
    if isinstance(args.input_lighting, int) and args.input_lighting < 0:
        raise ConfigError(
            f"`--input-lighting` is {args.input_lighting}; expected a lighting index >= 0 or 'area'."
        )
    if args.save_predictions is not None:
        checks.writable_dir("--save-predictions", args.save_predictions)
    _check_sampling_args(args)
    _object_fraction(args)
    _check_model_args(args)


def _validate_demo(args: argparse.Namespace) -> None:
    checks.replaceable_dir("--out", args.out)
    if args.checkpoint is not None:
        checks.need_dir("--checkpoint", args.checkpoint, "a model folder in our format")
        if not (args.checkpoint / MANIFEST_NAME).is_file():
            raise ConfigError(
                f"`--checkpoint` {args.checkpoint} has no {MANIFEST_NAME}: the demo takes a model "
                "folder in our format (`gaffer-diffusion export` or `init-random` writes one)."
            )
    if args.example is not None:
        checks.need_dir("--example", args.example, "a gaffer-data render folder")
    checks.int_range("--steps", args.steps, 1, checks.MAX_STEPS, "gaffer-tiny: 1, the paper: 50")
    checks.finite("--guidance", args.guidance, 0.0, 100.0)
    checks.int_range("--average-samples", args.average_samples, 1, checks.MAX_AVERAGE_SAMPLES)
    checks.int_range("--frames", args.frames, 0, checks.MAX_FRAMES, "0: no turntable; e.g. 24")
    checks.finite("--fps", args.fps, 0.0, checks.MAX_FPS, lo_open=True)
    checks.int_range("--seed", args.seed, 0, checks.MAX_SEED)
    checks.int_range("--batch-size", args.batch_size, 1, checks.MAX_BATCH)
    checks.int_range("--threads", args.threads, 1, 1024, "torch CPU threads; 1 is best here")
    if args.object_fraction is not None:
        checks.finite("--object-fraction", args.object_fraction, 0.0, 1.0, lo_open=True)
    if args.turntable_hdri is not None:
        from gaffer_envmap.bundled import bundled_hdris

        names = sorted(bundled_hdris())
        if args.turntable_hdri not in names:
            raise ConfigError(
                f"`--turntable-hdri` is {args.turntable_hdri!r}; pass one of the bundled HDRIs: "
                f"{', '.join(names)}."
            )
    _check_device_cheaply(args.device)


def _validate_prepare(args: argparse.Namespace) -> None:
    checks.int_range("--size", args.size, 8, checks.MAX_SIDE, "the model resolution, e.g. 256")
    checks.image_size("IMAGE", args.image)
    if isinstance(args.mask, Path):
        checks.need_file("--mask", args.mask, "the object mask (white = object), or 'auto'")
    checks.writable_file("--out", args.out)


def _envmap_path(value: str) -> Path:
    """`--envmap`: a file, or the name of an HDRI bundled with gaffer-envmap (issue 17)."""
    path = Path(value)
    if path.exists() or path.suffix:
        return path
    from gaffer_envmap.bundled import bundled_hdris

    return bundled_hdris().get(value, path)


def _relight(args: argparse.Namespace) -> int:
    _validate_relight(args)  # every flag and file, before torch is imported or weights load
    grid = args.image.is_dir() or args.envmaps is not None
    if grid:
        return _relight_grid(args)
    # the photo and its mask are read and checked before any weights load
    stem = args.out.with_suffix("")
    photo, alpha, mask_note = _photo_and_mask(args, args.image, args.mask, _mask_out(args.out))
    from gaffer_diffusion.conditioning import LightingMaps, RelightingConditions
    from gaffer_diffusion.photo import prepare_photo
    from gaffer_diffusion.pipelines import RelightPipeline

    _device(args)  # a CUDA device torch cannot use is refused before the weights load
    model = _load_model(args.checkpoint, args.base_model)
    pipe = RelightPipeline(model, _runtime(args))
    size = model.config.resolution
    prepared = prepare_photo(photo, alpha, size=size, compat=_compat(args))
    lighting = _lighting(args, size, args.turntable)
    sampling = _sampling(args)
    n = lighting.batch_size
    frames: list[np.ndarray] = []
    with _progress(n, "relight") as bar:
        for lo in range(0, n, args.batch_size):
            hi = min(lo + args.batch_size, n)
            model_in = prepared.model_input
            cond = RelightingConditions(
                image=model_in.image.expand(hi - lo, -1, -1, -1),
                lighting=LightingMaps(ldr=lighting.ldr[lo:hi], hdr=lighting.hdr[lo:hi]),
                mask=None if args.full_frame else model_in.mask.expand(hi - lo, -1, -1, -1),
            )
            # the same seed for every frame: the light moves, the noise does not (less flicker)
            out = pipe(cond, sampling, seeds=[args.seed] * (hi - lo))
            for j, relit in enumerate(out.images.cpu()):
                frames.append(_finish(args, prepared, relit, args.envmap, (lo + j, n)))
            bar.update(hi - lo)
    notes = "; ".join(
        x for x in (_size_note(args, frames[0]), _background_note(args), mask_note) if x
    )
    if args.turntable > 1:
        video = _write_turntable(args, stem, frames)
        print(f"wrote {len(frames)} frames {stem}_000.png ... and {video}; {notes}")
    else:
        _save_png(args.out, frames[0])
        print(f"wrote {args.out}; {notes}")
    return 0


def _write_turntable(args: argparse.Namespace, stem: Path, frames: list[np.ndarray]) -> Path:
    """`STEM_000.png ...` and the animation, complete or absent (issue 17): written to a hidden
    staging folder, then moved in; an earlier run's frames of this prefix (more of them, or the other
    video format) are removed only then, so no mix of old and new frames is left."""
    import glob

    from gaffer_diffusion._atomic_dir import staged_files
    from gaffer_diffusion._video import write_animation

    name = glob.escape(stem.name)
    digits = "[0-9]" * 3
    stale = [f"{name}_{digits}.png", f"{name}_{digits}[0-9].png", f"{name}.gif", f"{name}.mp4"]
    with staged_files(stem.parent, stale) as stage:
        for k, frame in enumerate(frames):
            _save_png(stage / f"{stem.name}_{k:03d}.png", frame)
        video = write_animation(
            [f[..., :3] for f in frames], stage / stem.name, fmt=args.video, fps=args.fps
        )
    return stem.parent / video.name


def _size_note(args: argparse.Namespace, image: np.ndarray) -> str:
    h, w = image.shape[:2]
    if args.output_size == "model":
        return f"{w}x{h}: the model's crop (--output-size model)"
    return f"{w}x{h}, the input's size, detail: {args.detail} (--output-size model for the crop)"


_IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".webp")
_ENVMAP_SUFFIXES = (".exr", ".hdr")


def _files(folder: Path, suffixes: tuple[str, ...], what: str, flag: str) -> list[Path]:
    files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in suffixes)
    if not files:
        raise InputValueError(
            f"`{flag}` {folder} holds no {what} ({', '.join(suffixes)} files directly in it)."
        )
    return files


def _relight_grid(args: argparse.Namespace) -> int:
    """Every image x every map, batched, one progress bar: OUT/<image stem>/<map stem>.png.

    Each output is written atomically; an image that cannot be read or relit is reported and the
    others go on (exit status 1 when any failed)."""
    folder = args.image.is_dir()
    images = _files(args.image, _IMAGE_SUFFIXES, "images", "IMAGE") if folder else [args.image]
    if isinstance(args.mask, Path) and folder and not args.mask.is_dir():
        raise ConfigError(
            "With a folder of images, `--mask` must be a folder of masks too (or 'auto')."
        )
    failed: list[str] = []
    loaded: list[tuple[Path, Photo, np.ndarray]] = []
    notes: list[str] = []
    for path in images:
        mask = (
            args.mask / path.name
            if isinstance(args.mask, Path) and args.mask.is_dir()
            else args.mask
        )
        try:
            photo, alpha, note = _photo_and_mask(
                args, path, mask, args.out / f"{path.stem}.mask.png"
            )
        except GafferDiffusionError as exc:
            if not folder:
                raise
            failed.append(f"{path.name}: {exc}")
            continue
        loaded.append((path, photo, alpha))
        notes += [note] if note else []
    if not loaded:
        raise InputValueError(f"None of the {len(images)} images could be used; {failed[0]}")
    import torch

    from gaffer_diffusion.conditioning import LightingMaps, RelightingConditions
    from gaffer_diffusion.photo import prepare_photo
    from gaffer_diffusion.pipelines import RelightPipeline

    _device(args)  # a CUDA device torch cannot use is refused before the weights load
    model = _load_model(args.checkpoint, args.base_model)
    pipe = RelightPipeline(model, _runtime(args))
    size = model.config.resolution
    prepared = [prepare_photo(p, a, size=size, compat=_compat(args)) for _, p, a in loaded]
    if args.envmaps is not None:
        maps = _files(args.envmaps, _ENVMAP_SUFFIXES, "environment maps", "--envmaps")
        lights = [(m.stem, m, _envmap_lighting(args, m, size)) for m in maps]
    else:
        label = args.envmap.stem if args.envmap is not None else args.ldr.stem
        lights = [(label, args.envmap, _lighting(args, size, 0))]
    jobs = [(i, e) for i in range(len(loaded)) for e in range(len(lights))]
    sampling = _sampling(args)
    args.out.mkdir(parents=True, exist_ok=True)
    written = 0
    with _progress(len(jobs), "relight") as bar:
        for lo in range(0, len(jobs), args.batch_size):
            chunk = jobs[lo : lo + args.batch_size]
            cond = RelightingConditions(
                image=torch.cat([prepared[i].model_input.image for i, _ in chunk]),
                mask=None
                if args.full_frame
                else torch.cat([prepared[i].model_input.mask for i, _ in chunk]),
                lighting=LightingMaps(
                    ldr=torch.cat([lights[e][2].ldr for _, e in chunk]),
                    hdr=torch.cat([lights[e][2].hdr for _, e in chunk]),
                ),
            )
            # one seed for every item: a result does not depend on the batch it landed in
            out = pipe(cond, sampling, seeds=[args.seed] * len(chunk))
            for (i, e), image in zip(chunk, out.images.cpu(), strict=True):
                dest = args.out / loaded[i][0].stem / f"{lights[e][0]}.png"
                try:
                    _save_png(dest, _finish(args, prepared[i], image, lights[e][1]))
                    written += 1
                except (GafferDiffusionError, OSError, ValueError) as exc:
                    failed.append(f"{dest}: {exc}")
            bar.update(len(chunk))
    print(
        f"wrote {written} images ({len(loaded)} inputs x {len(lights)} maps) under {args.out}; "
        f"{_background_note(args)}" + "".join(f"; {n}" for n in notes[:1])
    )
    if failed:
        print(f"error: {len(failed)} failed (the others were written):", file=sys.stderr)
        for line in failed:
            print(f"  {line}", file=sys.stderr)
        return 1
    return 0


def _read_dir_images(folder: Path, names: Sequence[str], channels: str) -> torch.Tensor:
    import numpy as np
    import torch
    from PIL import Image

    arrs = []
    for name in names:
        with Image.open(folder / name) as im:
            arrs.append(np.asarray(im.convert(channels), np.float32) / 255.0)
    for name, arr in zip(names, arrs, strict=True):
        if arr.shape != arrs[0].shape:
            raise InputValueError(
                f"`{folder / name}` has shape {arr.shape}, but `{folder / names[0]}` has "
                f"{arrs[0].shape}: every image must have the same size."
            )
    t = torch.from_numpy(np.stack(arrs))
    return t.permute(0, 3, 1, 2) if t.ndim == 4 else t[:, None]


def _perceptual_arg(args: argparse.Namespace) -> Any:
    from gaffer_diffusion.errors import MetricUnavailableError
    from gaffer_diffusion.metrics import load_perceptual

    if args.no_perceptual:
        if args.lpips_backbone is not None:
            raise ConfigError("Pass `--lpips-backbone` or `--no-perceptual`, not both.")
        return None
    if args.lpips_backbone is None:
        return "auto"
    try:
        return load_perceptual(args.lpips_backbone)
    except MetricUnavailableError as exc:
        raise InputValueError(str(exc)) from exc


def _object_fraction(args: argparse.Namespace) -> float | None:
    if args.object_fraction is not None:
        if not 0.0 < args.object_fraction <= 1.0:
            raise ConfigError(
                f"`--object-fraction` is {args.object_fraction}; pass a fraction in (0, 1], e.g. 0.75."
            )
        return float(args.object_fraction)
    return _suggestion(args).object_fraction


def _evaluate(args: argparse.Namespace) -> int:
    folders = args.pred is not None or args.gt is not None
    if args.dataset is not None and folders:
        raise ConfigError(
            "Pass either `--dataset DIR --checkpoint CKPT` (relight and score a rendered dataset) or "
            "`--pred DIR --gt DIR` (score existing predictions), not both."
        )
    if args.dataset is None and (args.pred is None or args.gt is None):
        raise ConfigError(
            "Pass `--dataset DIR --checkpoint CKPT`, or both `--pred DIR` and `--gt DIR`."
        )
    _validate_evaluate(args)  # every flag and file, before torch is imported or weights load
    if args.dataset is not None:
        return _evaluate_dataset(args)
    return _evaluate_folders(args)


def _evaluate_dataset(args: argparse.Namespace) -> int:
    from gaffer_diffusion.evaluation import EvaluationConfig, dataset_pairs, evaluate_dataset

    if args.batch_size < 1:
        raise ConfigError(f"`--batch-size` is {args.batch_size}; expected >= 1.")
    pairs = dataset_pairs(
        args.dataset,
        input_lighting=args.input_lighting,
        envmap_dirs=[args.envmaps] if args.envmaps is not None else [],
        limit=args.limit,
    )
    perceptual = _perceptual_arg(args)
    from gaffer_diffusion.pipelines import RelightPipeline

    _device(args)  # a CUDA device torch cannot use is refused before the weights load
    model = _load_model(args.checkpoint, args.base_model)
    pipe = RelightPipeline(model, _runtime(args))
    config = EvaluationConfig(
        sampling=_sampling(args),
        seed=args.seed,
        batch_size=args.batch_size,
        compat=_compat(args),
        predictions_dir=args.save_predictions,
        progress=True,
        keep_background=not args.full_frame,
        object_fraction=_object_fraction(args),
    )
    settings = {
        "dataset": str(args.dataset),
        "checkpoint": "gaffer-tiny (shipped)" if args.checkpoint is None else str(args.checkpoint),
        "base_model": None if args.base_model is None else str(args.base_model),
        "input_lighting": args.input_lighting,
    }
    result = evaluate_dataset(pipe, pairs, config, perceptual=perceptual, settings=settings)
    if args.json:
        args.json.write_text(result.to_json() + "\n")
    if args.markdown:
        args.markdown.write_text(result.to_markdown() + "\n")
    print(result.to_markdown())
    print(f"\n{len(pairs)} pairs in {result.seconds:.1f} s: {result.summary()}")
    return 0


def _evaluate_folders(args: argparse.Namespace) -> int:
    from gaffer_diffusion.metrics import evaluate_images

    exts = {".png", ".jpg", ".jpeg"}
    pred_names = (
        {p.name for p in args.pred.iterdir() if p.suffix.lower() in exts}
        if args.pred.is_dir()
        else set()
    )
    gt_names = (
        {p.name for p in args.gt.iterdir() if p.suffix.lower() in exts}
        if args.gt.is_dir()
        else set()
    )
    names = sorted(pred_names & gt_names)
    if not names:
        raise InputValueError(
            f"No image file names common to `--pred` {args.pred} and `--gt` {args.gt}."
        )
    if len(names) < len(gt_names):
        logger.warning("%d ground-truth images have no prediction", len(gt_names) - len(names))
    pred = _read_dir_images(args.pred, names, "RGB")
    gt = _read_dir_images(args.gt, names, "RGB")
    mask = _read_dir_images(args.mask_dir, names, "L") if args.mask_dir else None
    perceptual = _perceptual_arg(args)
    report = evaluate_images(pred, gt, mask=mask, names=names, perceptual=perceptual)  # type: ignore[arg-type]
    if args.json:
        args.json.write_text(report.to_json())
    if args.markdown:
        args.markdown.write_text(report.to_markdown() + "\n")
    print(report.to_markdown())
    return 0


def _demo(args: argparse.Namespace) -> int:
    _validate_demo(args)
    import torch

    from gaffer_diffusion.demo import DemoConfig, run_demo

    torch.set_num_threads(args.threads)
    config = DemoConfig(
        out=args.out,
        checkpoint=args.checkpoint,
        example=args.example,
        num_inference_steps=args.steps,
        guidance_scale=args.guidance,
        average_samples=args.average_samples,
        mirror_average=args.mirror_average,
        frames=args.frames,
        turntable_hdri=args.turntable_hdri,
        fps=args.fps,
        seed=args.seed,
        batch_size=args.batch_size,
        device=_device(args),
        extra_hdris=not args.no_extra_hdris,
        keep_background=not args.full_frame,
        compat=args.compat,
        object_fraction=args.object_fraction,
    )
    result = run_demo(config)
    gif = f", {result.turntable_gif}" if result.turntable_gif is not None else ""
    print(
        f"relit {result.images} images in {result.seconds:.1f} s; wrote {result.report_html}, "
        f"{result.metrics_json}{gif} and the PNGs under {result.out}\n"
        f"{result.summary}"
    )
    return 0


def _add_authors_commands(sub: Any) -> None:
    """`prepare` and `check` (issue 15): what the model sees, and whether the authors' files are complete."""
    pr = sub.add_parser(
        "prepare", help="write the model-ready square input (on white) and its mask, as PNGs"
    )
    pr.add_argument("image", type=Path, help="object image: RGBA, or RGB with --mask")
    pr.add_argument(
        "--mask",
        type=_mask_arg,
        help="object mask (white = object) for an RGB image, or 'auto' (GrabCut, written as "
        "OUT.mask.png)",
    )
    pr.add_argument("--out", type=Path, required=True, help="output PNG (the mask: OUT_mask.png)")
    pr.add_argument(
        "--compat",
        choices=get_args(PrepareCompat),
        default="default",
        help="'neural-gaffer': the authors' real-image steps (thumbnail 512, alpha > 0 box, "
        "int(side / 0.75), LANCZOS on RGBA, white, truncation); 'default': ours",
    )
    pr.add_argument("--size", type=int, default=256, help="output side (the model resolution)")
    ck = sub.add_parser(
        "check",
        help="validate the authors' checkpoint-80000/ and a Zero-1-to-3 XL base before a long run",
    )
    ck.add_argument(
        "--checkpoint", type=Path, required=True, help="checkpoint-80000/ or its parent"
    )
    ck.add_argument(
        "--base-model", type=Path, required=True, help="Zero-1-to-3 XL diffusers folder"
    )


def _prepare(args: argparse.Namespace) -> int:
    _validate_prepare(args)
    _check_photo_flags(args)
    import numpy as np

    from gaffer_diffusion.photo import prepare_photo

    photo, alpha, note = _photo_and_mask(args, args.image, args.mask, _mask_out(args.out))
    prepared = prepare_photo(photo, alpha, size=args.size, compat=args.compat).model_input
    mask_out = args.out.with_name(f"{args.out.stem}_mask.png")
    _save_png(args.out, prepared.image[0])
    arr = (prepared.mask[0, 0].clamp(0, 1).numpy() * 255.0).round().astype(np.uint8)
    _save_png(mask_out, arr)
    extra = f"; {note}" if note else ""
    print(f"wrote {args.out} and {mask_out} ({args.size}x{args.size}, compat={args.compat}){extra}")
    return 0


def _check(args: argparse.Namespace) -> int:
    # no early refusal here: `check` reports missing folders in its own report (exit status 2)
    from gaffer_diffusion.release_check import check_release

    result = check_release(args.checkpoint, args.base_model)
    print(result.report())
    return 0 if result.ok else 2


def _init_random(args: argparse.Namespace) -> int:
    checks.int_range("--seed", args.seed, 0, checks.MAX_SEED)
    checks.writable_dir("--out", args.out)
    from gaffer_diffusion.configs import get_preset
    from gaffer_diffusion.loading import save_pretrained
    from gaffer_diffusion.models.build import build_model

    model = build_model(get_preset(args.preset), seed=args.seed)
    save_pretrained(model, args.out)
    print(f"wrote a random-weight {args.preset} model to {args.out}")
    return 0


def _training_module(what: str) -> Any:
    """`gaffer_diffusion.training`, or a clear error naming the `train` extra."""
    try:
        import gaffer_diffusion.training as training
        import gaffer_diffusion.training.loop  # noqa: F401  (accelerate and gaffer-data load here)
    except ImportError as exc:
        raise MissingDependencyError(
            f'{what} needs the train extra ({exc.name} is missing): pip install "gaffer-diffusion[train]"'
        ) from exc
    return training


def _export(args: argparse.Namespace) -> int:
    checks.need_dir(
        "checkpoint", args.checkpoint, "a checkpoint-NNNNNNNN/ folder of a training run"
    )
    checks.writable_dir("--out", args.out)
    if args.out.exists() and any(args.out.iterdir()):
        raise ConfigError(f"`--out` {args.out} exists and is not empty; pass a new folder.")
    load_checkpoint_model = _training_module("Exporting").loop.load_checkpoint_model
    from gaffer_diffusion.loading import save_pretrained

    model = load_checkpoint_model(args.checkpoint, use_ema=not args.raw)
    from gaffer_diffusion.suggested import suggestion_from_training_config
    from gaffer_diffusion.training.checkpoint import read_state

    # the encoding, framing and sampler it was trained and validated with travel with the weights
    suggested = suggestion_from_training_config(read_state(args.checkpoint).config)
    out = save_pretrained(model, args.out, suggested=suggested)
    print(f"wrote {'trained' if args.raw else 'EMA'} weights of {args.checkpoint} to {out}")
    return 0


def _train(args: argparse.Namespace) -> int:
    import json

    checks.need_file(
        "--config", args.config, "a training config JSON (packages/gaffer-diffusion/configs/)"
    )
    try:
        json.loads(args.config.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputValueError(
            f"`--config` {args.config} is not valid JSON ({exc}); fix the file."
        ) from exc
    training = _training_module("Training")
    load_config, train = training.load_config, training.train
    result = train(load_config(args.config), resume=args.resume)
    print(
        f"trained steps {result.start_step} -> {result.step} ({result.stop_reason}) in "
        f"{result.seconds:.0f} s; checkpoint {result.checkpoint}; final model {result.final_model}"
    )
    for v in result.validations[-1:]:
        print(f"validation PSNR {v.psnr:.2f} dB (unrelit input: {v.psnr_identity:.2f} dB)")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `gaffer-diffusion` console script; returns the exit status."""
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        match args.command:
            case "demo":
                return _demo(args)
            case "relight":
                return _relight(args)
            case "evaluate":
                return _evaluate(args)
            case "init-random":
                return _init_random(args)
            case "prepare":
                return _prepare(args)
            case "check":
                return _check(args)
            case "train":
                return _train(args)
            case "export":
                return _export(args)
            case "app":
                from gaffer_diffusion.app import run_app  # Gradio loads only here

                return run_app(args)
    except GafferError as exc:  # any gaffer package's error (an unreadable EXR is also an OSError)
        print(f"error: {exc.diagnostics()}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C: one line, not a traceback; outputs are written atomically
        print(
            "interrupted (Ctrl-C): stopped; files already written are complete "
            "(train: --resume continues from the last checkpoint)",
            file=sys.stderr,
        )
        return 130
    except OSError as exc:  # an unwritable or clashing output path, a full disk
        print(f"error: {exc}. Check the path's permissions and free space.", file=sys.stderr)
        return 2
    except Exception as exc:  # errors from gaffer-envmap (reading EXRs, poses) carry their own fix
        if type(exc).__module__.startswith("gaffer_envmap"):
            print(f"error: {exc}", file=sys.stderr)
            return 2
        raise
    return 1


if __name__ == "__main__":
    sys.exit(main())
