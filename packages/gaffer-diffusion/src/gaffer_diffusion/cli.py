"""Command line: `gaffer-diffusion relight | evaluate | init-random`.

    gaffer-diffusion relight IMAGE --envmap ENV.exr (--w2c W2C.npy | --azimuth DEG --elevation DEG)
        --checkpoint CKPT [--base-model DIR] --out OUT.png [--steps 50] [--guidance 3] [--seed 0]
        [--turntable N]
    gaffer-diffusion relight IMAGE --ldr LDR.png --hdr HDR.png --checkpoint CKPT ... (pre-encoded maps)
    gaffer-diffusion evaluate --pred DIR --gt DIR [--mask-dir DIR] [--lpips-backbone FILE] [--json F]
    gaffer-diffusion init-random --preset tiny --out DIR   (random weights in our format, for demos)

`--checkpoint` is either our format (a folder with `gaffer_model.json`) or the authors' release
(`checkpoint-80000/`), which also needs `--base-model` (a local Zero-1-to-3 XL diffusers folder).
"""

import argparse
import logging
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from gaffer_diffusion.conditioning import LightingMaps, RelightingConditions, lighting_from_envmap
from gaffer_diffusion.configs import PRESETS, get_preset
from gaffer_diffusion.errors import ConfigError, GafferDiffusionError, InputValueError
from gaffer_diffusion.loading import (
    MANIFEST_NAME,
    load_authors_release,
    load_pretrained,
    save_pretrained,
)
from gaffer_diffusion.models.model import NeuralGafferModel
from gaffer_diffusion.pipelines import RelightPipeline, RuntimeConfig, SamplingConfig
from gaffer_diffusion.preprocess import load_object_image
from gaffer_diffusion.schedulers import SCHEDULERS

logger = logging.getLogger(__name__)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="gaffer-diffusion", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("relight", help="relight one object image under an environment map")
    r.add_argument("image", type=Path, help="object image; RGBA, or RGB with --mask")
    r.add_argument(
        "--mask", type=Path, help="object mask (white = object) for images without alpha"
    )
    light = r.add_argument_group("lighting: --envmap with a pose, or pre-encoded --ldr/--hdr maps")
    light.add_argument(
        "--envmap", type=Path, help="equirectangular HDR map (.exr/.hdr), Blender z-up"
    )
    light.add_argument("--w2c", type=Path, help="3x4 or 4x4 Blender world-to-camera .npy")
    light.add_argument("--azimuth", type=float, help="orbit camera azimuth, degrees")
    light.add_argument("--elevation", type=float, help="orbit camera elevation, degrees")
    light.add_argument("--ldr", type=Path, help="pre-encoded camera-frame LDR map (PNG)")
    light.add_argument("--hdr", type=Path, help="pre-encoded camera-frame HDR map (PNG)")
    light.add_argument(
        "--compat",
        choices=("neural-gaffer", "default"),
        default="neural-gaffer",
        help="lighting encoding; 'neural-gaffer' matches the released checkpoint (default)",
    )
    light.add_argument(
        "--sanitize",
        choices=("zero", "clamp", "raise"),
        default="zero",
        help="NaN/Inf/negative env-map pixels: set to 0 (default), clamp, or fail",
    )
    r.add_argument(
        "--checkpoint", type=Path, required=True, help="our model folder or checkpoint-80000/"
    )
    r.add_argument(
        "--base-model", type=Path, help="Zero-1-to-3 XL folder (authors' checkpoint only)"
    )
    r.add_argument(
        "--out", type=Path, required=True, help="output PNG (turntable: frame prefix + GIF)"
    )
    r.add_argument("--steps", type=int, default=50)
    r.add_argument("--guidance", type=float, default=3.0)
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--scheduler", choices=SCHEDULERS, default="ddim")
    r.add_argument(
        "--turntable", type=int, default=0, help="N frames of the light spinning about up"
    )
    r.add_argument("--batch-size", type=int, default=4, help="frames per batch (turntable)")
    r.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    r.add_argument("--dtype", choices=("float32", "float16", "bfloat16"), default="float32")

    e = sub.add_parser(
        "evaluate", help="score predicted images against ground truth (matched by name)"
    )
    e.add_argument("--pred", type=Path, required=True)
    e.add_argument("--gt", type=Path, required=True)
    e.add_argument(
        "--mask-dir", type=Path, help="masks with the same file names (channel alignment)"
    )
    e.add_argument(
        "--lpips-backbone", type=Path, help="torchvision AlexNet weights for standard LPIPS"
    )
    e.add_argument("--json", type=Path, help="write the full report as JSON")
    e.add_argument("--markdown", type=Path, help="write the table of means as markdown")

    i = sub.add_parser(
        "init-random", help="save a random-weight model in our format (demos, tests)"
    )
    i.add_argument("--preset", choices=PRESETS, default="tiny")
    i.add_argument("--seed", type=int, default=0)
    i.add_argument("--out", type=Path, required=True)
    return p


def _load_model(checkpoint: Path, base_model: Path | None) -> NeuralGafferModel:
    if (checkpoint / MANIFEST_NAME).is_file():
        return load_pretrained(checkpoint).model
    if base_model is None:
        raise ConfigError(
            f"`--checkpoint` {checkpoint} is not a gaffer-diffusion model folder (no {MANIFEST_NAME}), so "
            "it is taken as the authors' release, which needs `--base-model DIR` (a local Zero-1-to-3 XL "
            "diffusers folder with vae/, image_encoder/, scheduler/, unet/config.json)."
        )
    result = load_authors_release(checkpoint, base_model)
    logger.info("%s", result.report.summary())
    return result.model


def _read_map_png(path: Path, size: int) -> torch.Tensor:
    try:
        with Image.open(path) as im:
            arr = np.asarray(im.convert("RGB").resize((size, size), Image.Resampling.BILINEAR))
    except (OSError, ValueError) as exc:
        raise InputValueError(f"Could not read the lighting map `{path}`: {exc}") from exc
    return torch.from_numpy(arr.astype(np.float32) / 255.0).permute(2, 0, 1)[None]


def _lighting(args: argparse.Namespace, size: int, frames: int) -> LightingMaps:
    if args.ldr is not None or args.hdr is not None:
        if args.ldr is None or args.hdr is None or args.envmap is not None:
            raise ConfigError("Pass both `--ldr` and `--hdr` (pre-encoded maps) and no `--envmap`.")
        if frames > 1:
            raise ConfigError("`--turntable` needs `--envmap` (pre-encoded maps cannot be spun).")
        return LightingMaps(ldr=_read_map_png(args.ldr, size), hdr=_read_map_png(args.hdr, size))
    if args.envmap is None:
        raise ConfigError(
            "Pass `--envmap ENV.exr` with a pose, or pre-encoded `--ldr` and `--hdr` maps."
        )
    from gaffer_envmap.io import read_envmap
    from gaffer_envmap.poses import W2CBlender, orbit_w2c_blender

    if args.w2c is not None:
        if args.azimuth is not None or args.elevation is not None:
            raise ConfigError("Pass either `--w2c` or `--azimuth`/`--elevation`, not both.")
        pose = W2CBlender.from_array(np.load(args.w2c, allow_pickle=False))
    elif args.azimuth is not None and args.elevation is not None:
        pose = orbit_w2c_blender(args.azimuth, args.elevation)
    else:
        raise ConfigError(
            "Give the camera: `--w2c W2C.npy`, or both `--azimuth` and `--elevation`."
        )
    env = read_envmap(args.envmap, sanitize=args.sanitize)
    n = max(frames, 1)
    spin = torch.arange(n, dtype=torch.float64) * (360.0 / n) if frames > 1 else 0.0
    return lighting_from_envmap(env, [pose] * n, size=size, compat=args.compat, spin_deg=spin)


def _save_png(path: Path, image: torch.Tensor) -> None:
    arr = (image.clamp(0, 1).permute(1, 2, 0).cpu().numpy() * 255.0).round().astype(np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(arr).save(path)


def _relight(args: argparse.Namespace) -> int:
    if args.turntable < 0 or args.batch_size < 1:
        raise ConfigError("`--turntable` must be >= 0 and `--batch-size` >= 1.")
    model = _load_model(args.checkpoint, args.base_model)
    size = model.config.resolution
    prepared = load_object_image(args.image, mask_path=args.mask, size=size)
    lighting = _lighting(args, size, args.turntable)
    pipe = RelightPipeline(model, RuntimeConfig(device=args.device, dtype=args.dtype))
    sampling = SamplingConfig(
        num_inference_steps=args.steps, guidance_scale=args.guidance, scheduler=args.scheduler
    )
    n = lighting.batch_size
    frames: list[torch.Tensor] = []
    start = time.perf_counter()
    for lo in range(0, n, args.batch_size):
        hi = min(lo + args.batch_size, n)
        cond = RelightingConditions(
            image=prepared.image.expand(hi - lo, -1, -1, -1),
            lighting=LightingMaps(ldr=lighting.ldr[lo:hi], hdr=lighting.hdr[lo:hi]),
        )
        # the same seed for every frame: the light moves, the noise does not (less flicker)
        out = pipe(cond, sampling, seeds=[args.seed] * (hi - lo))
        frames.extend(out.images.cpu())
        print(f"relit {hi}/{n} in {time.perf_counter() - start:.1f} s", file=sys.stderr)
    if args.turntable > 1:
        stem = args.out.with_suffix("")
        for k, frame in enumerate(frames):
            _save_png(Path(f"{stem}_{k:03d}.png"), frame)
        gif = [Image.open(Path(f"{stem}_{k:03d}.png")).convert("RGB") for k in range(len(frames))]
        gif[0].save(
            stem.with_suffix(".gif"), save_all=True, append_images=gif[1:], duration=80, loop=0
        )
        print(f"wrote {len(frames)} frames {stem}_000.png ... and {stem.with_suffix('.gif')}")
    else:
        _save_png(args.out, frames[0])
        print(f"wrote {args.out}")
    return 0


def _read_dir_images(folder: Path, names: Sequence[str], channels: str) -> torch.Tensor:
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


def _evaluate(args: argparse.Namespace) -> int:
    from gaffer_diffusion.errors import MetricUnavailableError
    from gaffer_diffusion.metrics import evaluate_images, load_perceptual

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
    perceptual: object = "auto"
    if args.lpips_backbone is not None:
        try:
            perceptual = load_perceptual(args.lpips_backbone)
        except MetricUnavailableError as exc:
            raise InputValueError(str(exc)) from exc
    report = evaluate_images(pred, gt, mask=mask, names=names, perceptual=perceptual)  # type: ignore[arg-type]
    if args.json:
        args.json.write_text(report.to_json())
    if args.markdown:
        args.markdown.write_text(report.to_markdown() + "\n")
    print(report.to_markdown())
    return 0


def _init_random(args: argparse.Namespace) -> int:
    model = get_preset(args.preset).setup(seed=args.seed)
    save_pretrained(model, args.out)
    print(f"wrote a random-weight {args.preset} model to {args.out}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `gaffer-diffusion` console script; returns the exit status."""
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        match args.command:
            case "relight":
                return _relight(args)
            case "evaluate":
                return _evaluate(args)
            case "init-random":
                return _init_random(args)
    except GafferDiffusionError as exc:
        print(f"error: {exc.diagnostics()}", file=sys.stderr)
        return 2
    except Exception as exc:  # errors from gaffer-envmap (reading EXRs, poses) carry their own fix
        if type(exc).__module__.startswith("gaffer_envmap"):
            print(f"error: {exc}", file=sys.stderr)
            return 2
        raise
    return 1


if __name__ == "__main__":
    sys.exit(main())
