"""The requests of `relight`, `evaluate` and `insert` (`cli._requests`), each built once from the parsed
arguments by one function (`relight_request`, `evaluate_request`, `insert_request`) that performs
every refusal, before any weights load; nothing below these functions reads the `argparse.Namespace`.

Flags and paths are checked first, without torch (a refusal takes a fraction of a second; the
`test_cli_refusals` runner checks that torch is not imported); then each file is read, once: the
environment map(s) and `--w2c` (numpy only), the model folder's sampling (a JSON read), and last the
photos (which import torch through `gaffer_diffusion.photo`).
"""

from __future__ import annotations

import argparse
import glob
import importlib.util
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gaffer_diffusion import _cli_checks as checks
from gaffer_diffusion.cli._common import _ENVMAP_SUFFIXES, _IMAGE_SUFFIXES, _files
from gaffer_diffusion.cli._flag_checks import _check_checkpoint_args, _check_device_cheaply
from gaffer_diffusion.cli._lighting import _check_envmap_arg, _read_envmap, _read_w2c
from gaffer_diffusion.cli._photo import _mask_out, _photo_and_mask
from gaffer_diffusion.cli._requests import (
    EncodedLight,
    EnvmapLight,
    EvaluateDatasetRequest,
    EvaluateFoldersRequest,
    EvaluateRequest,
    InsertRequest,
    Light,
    ModelChoice,
    OutputLook,
    PhotoMask,
    RelightRequest,
    Reports,
    RuntimeChoice,
)
from gaffer_diffusion.errors import (
    ConfigError,
    GafferDiffusionError,
    InputValueError,
    MissingDependencyError,
)
from gaffer_diffusion.suggested import DefaultSampling, LatentModeName

if TYPE_CHECKING:
    from gaffer_diffusion.insert_geometry import BackgroundCamera, InsertLighting, KeyLight
    from gaffer_diffusion.photo import Photo
    from gaffer_diffusion.pipelines import RuntimeConfig, SamplingConfig

SUN_SIZE_DEG = 0.53
"""The sun's angular diameter, degrees: the size of a `--sun-at` key light."""


# --- the model and its sampling (relight, evaluate, insert) ---------------------------------------


def _check_sampling_args(args: argparse.Namespace) -> None:
    checks.int_range("--steps", args.steps, 1, checks.MAX_STEPS, "gaffer-tiny: 1, the paper: 50")
    checks.finite("--guidance", args.guidance, 0.0, 100.0)
    checks.int_range("--average-samples", args.average_samples, 1, checks.MAX_AVERAGE_SAMPLES)
    checks.int_range("--batch-size", args.batch_size, 1, checks.MAX_BATCH)
    checks.int_range("--seed", args.seed, 0, checks.MAX_SEED)
    _check_device_cheaply(args.device)
    _check_autocast(args.autocast, args.dtype)


def _check_autocast(autocast: bool | None, dtype: str) -> None:
    if autocast and dtype in ("float32", "auto"):
        raise ConfigError(
            f"`--autocast` with `--dtype {dtype}`: autocast runs the UNet in a lower precision "
            "named by --dtype: add `--dtype float16` (the authors') or `--dtype bfloat16`."
        )


def _check_model_args(args: argparse.Namespace) -> None:
    """`--checkpoint` / `--base-model` exist and go together."""
    if args.checkpoint is not None:
        checks.need_dir(
            "--checkpoint",
            args.checkpoint,
            "a model folder (gaffer_model.json) or checkpoint-80000/",
        )
    if args.base_model is not None:
        checks.need_dir("--base-model", args.base_model, "a local Zero-1-to-3 XL diffusers folder")
    _check_checkpoint_args(args.checkpoint, args.base_model)


def _defaults(args: argparse.Namespace) -> DefaultSampling:
    """The model's own sampling: the shipped gaffer-tiny's without `--checkpoint`, else what the
    model folder records (the paper's for the authors' release or a folder that records none). A JSON
    read, no torch."""
    from gaffer_diffusion import pretrained
    from gaffer_diffusion.suggested import read_default_sampling

    checkpoint = args.checkpoint
    folder = pretrained.gaffer_tiny_path() if checkpoint is None else Path(checkpoint).expanduser()
    return read_default_sampling(Path(folder))


def _sampling_parts(
    args: argparse.Namespace, defaults: DefaultSampling
) -> tuple[DefaultSampling, LatentModeName]:
    """`defaults` with every sampling flag the user gave, and the latent mode: `--latent-mode`, else
    the one the encoding brings."""
    sampling = defaults.override(
        num_inference_steps=args.steps,
        guidance_scale=args.guidance,
        average_samples=args.average_samples,
        mirror_average=args.mirror_average,
        compat=args.compat,
    )
    return sampling, args.latent_mode or sampling.latent_mode


def _model_choice(args: argparse.Namespace, defaults: DefaultSampling | None = None) -> ModelChoice:
    """The model flags, after `_check_sampling_args` and `_check_model_args`; the model folder's
    sampling is read here, once per call (or given, when the caller read it already)."""
    sampling, latent_mode = _sampling_parts(args, _defaults(args) if defaults is None else defaults)
    return ModelChoice(
        checkpoint=args.checkpoint,
        base_model=args.base_model,
        sampling=sampling,
        latent_mode=latent_mode,
        scheduler=args.scheduler,
        runtime=_runtime_choice(args, sampling.compat),
        seed=args.seed,
        batch_size=args.batch_size,
        full_frame=args.full_frame,
    )


def _runtime_choice(args: argparse.Namespace, compat: str) -> RuntimeChoice:
    _check_autocast(args.autocast, args.dtype)
    return RuntimeChoice(
        device=args.device, dtype=args.dtype, autocast=args.autocast, compat=compat
    )


def _object_fraction_of(value: float | None, defaults: DefaultSampling) -> float | None:
    if value is not None:
        if not 0.0 < value <= 1.0:
            raise ConfigError(
                f"`--object-fraction` is {value}; pass a fraction in (0, 1], e.g. 0.75."
            )
        return float(value)
    return defaults.object_fraction


# One part of a request at a time, from parsed arguments: for tests and tools that ask what a command
# would use (`gaffer_diffusion.cli` re-exports them); the commands build the whole request instead.


def _compat(args: argparse.Namespace) -> Any:
    """`--compat`, else the lighting encoding the model was trained with."""
    return _sampling_parts(args, _defaults(args))[0].compat


def _latent_mode(args: argparse.Namespace) -> LatentModeName:
    """`--latent-mode`, else the one `--compat` (or the model's encoding) brings."""
    return _sampling_parts(args, _defaults(args))[1]


def _sampling(args: argparse.Namespace) -> SamplingConfig:
    """Every value the user leaves out is the model's own (its folder's `suggested_sampling`); an
    explicit 0 is refused by `SamplingConfig` (it used to mean "the default" silently)."""
    sampling, latent_mode = _sampling_parts(args, _defaults(args))
    return sampling.sampling_config(latent_mode=latent_mode, scheduler=args.scheduler)


def _object_fraction(args: argparse.Namespace) -> float | None:
    """`--object-fraction`, else the model's framing."""
    return _object_fraction_of(args.object_fraction, _defaults(args))


def _runtime(args: argparse.Namespace) -> RuntimeConfig:
    """Device and precision; `--dtype float16` on CUDA under `--compat neural-gaffer` autocasts the
    UNet with float32 weights, as the authors run it (official implementation §2)."""
    return _runtime_choice(args, _compat(args)).runtime_config()


def _envmap_lighting(args: argparse.Namespace, envmap: Path, size: int, frames: int = 0) -> Any:
    """The encoded maps of `envmap` seen from the command's camera (`EnvmapLight.maps`)."""
    light = EnvmapLight(path=envmap, env=_read_envmap(envmap, args.sanitize), pose=_pose(args))
    return light.maps(size, _compat(args), frames)


# --- photos ---------------------------------------------------------------------------------------


def _check_photo_flags(args: argparse.Namespace) -> None:
    """`--mask auto` / `--sam-checkpoint` / `--background` refused early, before any input is read."""
    sam = getattr(args, "sam_checkpoint", None)
    if sam is not None:
        if args.mask is not None:
            raise ConfigError("Pass `--mask` or `--sam-checkpoint`, not both.")
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


# --- relight --------------------------------------------------------------------------------------


def _pose(args: argparse.Namespace) -> Any:
    """The camera of `--w2c` (read here) or `--azimuth/--elevation`; numpy and gaffer-envmap only."""
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


def _lights(args: argparse.Namespace) -> tuple[Light, ...]:
    """The lighting flags checked and each map read once with `--sanitize` (its refusal before any
    weights load), with the camera; pre-encoded maps are read later, at the model's size."""
    if args.envmaps is not None:
        checks.need_dir("--envmaps", args.envmaps, "a folder of .exr/.hdr maps")
        maps = _files(args.envmaps, _ENVMAP_SUFFIXES, "environment maps", "--envmaps")
        envs = []
        for m in maps:
            checks.envmap_file("--envmaps", m)
            envs.append(_read_envmap(m, args.sanitize))
    elif args.ldr is not None or args.hdr is not None:
        if args.ldr is None or args.hdr is None or args.envmap is not None:
            raise ConfigError("Pass both `--ldr` and `--hdr` (pre-encoded maps) and no `--envmap`.")
        if args.turntable > 1:
            raise ConfigError("`--turntable` needs `--envmap` (pre-encoded maps cannot be spun).")
        checks.image_size("--ldr", args.ldr)
        checks.image_size("--hdr", args.hdr)
        return (EncodedLight(ldr=args.ldr, hdr=args.hdr),)
    elif args.envmap is None:
        raise ConfigError(
            "Pass `--envmap ENV.exr` (or `--envmaps DIR`) with a pose, or pre-encoded `--ldr` and "
            "`--hdr` maps."
        )
    else:
        _check_envmap_arg(args.envmap)
        maps, envs = [args.envmap], [_read_envmap(args.envmap, args.sanitize)]
    pose = _pose(args)  # reads and checks --w2c, or --azimuth/--elevation (numpy only)
    return tuple(EnvmapLight(path=m, env=e, pose=pose) for m, e in zip(maps, envs, strict=True))


def _check_turntable_memory(args: argparse.Namespace, width: int, height: int) -> None:
    """`--turntable N` keeps N frames (and N lighting pairs) in memory: refuse what cannot fit."""
    side = 128 if args.checkpoint is None else 512  # the model's side (512: the largest preset)
    out_px = side * side if args.output_size == "model" else width * height
    per_frame = 3 * 4 * out_px + 2 * 2 * 3 * side * side * 4  # frames + animation copies; E_L, E_H
    checks.fits_in_memory("--turntable", args.turntable * per_frame, f"{args.turntable} frames")


def _check_relight_outputs(args: argparse.Namespace, grid: bool) -> None:
    """Nothing `relight` writes may be a folder where a file goes (or the reverse) or replace an
    input, checked before any work."""
    inputs = [("IMAGE", args.image), ("--mask", args.mask)]
    if grid:  # OUT/<image stem>/<map>.png and OUT/<image stem>.mask.png
        images = (
            _files(args.image, _IMAGE_SUFFIXES, "images", "IMAGE")
            if args.image.is_dir()
            else [args.image]
        )
        stems = [p.stem for p in images]
        checks.writable_dir(
            "--out", args.out, files=[f"{glob.escape(s)}.mask.png" for s in stems], folders=stems
        )
        checks.not_an_input("--out", args.out, inputs)
        return
    width, height = checks.image_size("IMAGE", args.image)
    stem = args.out.with_suffix("")
    siblings = [] if isinstance(args.mask, Path) else [_mask_out(args.out)]  # a mask estimate
    if args.turntable > 1:  # STEM_000.png ... and STEM.gif / STEM.mp4
        siblings += [stem.with_name(f"{stem.name}_{k:03d}.png") for k in range(args.turntable)]
        siblings += [stem.with_name(f"{stem.name}.{ext}") for ext in ("gif", "mp4")]
    checks.writable_file("--out", args.out, siblings=siblings, suffixes=(".png",))  # PNGs only
    for written in (args.out, *siblings):  # none of what it writes may replace an input
        checks.not_an_input("--out", written, inputs)
    if args.turntable > 1:
        from gaffer_diffusion._video import NO_MP4, mp4_encoder

        if args.video == "mp4" and mp4_encoder() is None:
            raise MissingDependencyError(NO_MP4)
        _check_turntable_memory(args, width, height)


def _relight_photos(
    args: argparse.Namespace, grid: bool
) -> tuple[tuple[tuple[Path, PhotoMask], ...], tuple[str, ...]]:
    """Each photo and its mask read (photos that cannot be used: a folder's are listed and the others
    go on; one image's is refused)."""
    sam = args.sam_checkpoint
    if not grid:
        return ((args.image, _photo_and_mask(sam, args.image, args.mask, _mask_out(args.out))),), ()
    folder = args.image.is_dir()
    images = _files(args.image, _IMAGE_SUFFIXES, "images", "IMAGE") if folder else [args.image]
    if isinstance(args.mask, Path) and folder and not args.mask.is_dir():
        raise ConfigError(
            "With a folder of images, `--mask` must be a folder of masks too (or 'auto')."
        )
    failed: list[str] = []
    loaded: list[tuple[Path, PhotoMask]] = []
    for path in images:
        mask = (
            args.mask / path.name
            if isinstance(args.mask, Path) and args.mask.is_dir()
            else args.mask
        )
        try:
            read = _photo_and_mask(sam, path, mask, args.out / f"{path.stem}.mask.png")
        except GafferDiffusionError as exc:
            if not folder:
                raise
            failed.append(f"{path.name}: {exc}")
            continue
        loaded.append((path, read))
    if not loaded:
        raise InputValueError(f"None of the {len(images)} images could be used; {failed[0]}")
    return tuple(loaded), tuple(failed)


def relight_request(args: argparse.Namespace) -> RelightRequest:
    """`gaffer-diffusion relight`'s arguments as a request: every flag and file checked, each map and
    `--w2c` read, then the photos (a one-line refusal naming the flag for anything wrong)."""
    checks.need_path(
        "IMAGE", args.image, "an object photo (its alpha, or --mask, marks the object) or a folder"
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
    lights = _lights(args)
    if isinstance(args.mask, Path):
        checks.need_path("--mask", args.mask, "the object mask (white = object), or 'auto'")
    if args.sam_checkpoint is not None:
        checks.need_file("--sam-checkpoint", args.sam_checkpoint, "a Segment Anything checkpoint")
    _check_photo_flags(args)
    _check_model_args(args)
    _check_relight_outputs(args, grid)
    model = _model_choice(args)
    photos, unreadable = _relight_photos(args, grid)  # before any weights load
    return RelightRequest(
        model=model,
        look=OutputLook(
            output_size=args.output_size,
            detail=args.detail,
            background=args.background,
            fov=args.fov,
        ),
        out=args.out,
        photos=photos,
        unreadable=unreadable,
        lights=lights,
        grid=grid,
        turntable=args.turntable,
        video=args.video,
        fps=args.fps,
    )


# --- evaluate -------------------------------------------------------------------------------------


def _check_envmaps(pairs: Sequence[Any], policy: str) -> None:
    """`--sanitize`: read each env map the pairs are lit by once with `policy`, before the model loads.

    The scoring (`gaffer_diffusion.evaluation`) reads the maps again with "zero", which yields the
    same pixels as every policy that passes here ("raise" sets only tiny negatives to 0, "strict"
    passes only clean maps), except "clamp" on a map holding +Inf: that is refused here rather than
    scored with a different map than asked for.
    """
    import numpy as np

    from gaffer_envmap.errors import NonFiniteError
    from gaffer_envmap.io import read_envmap

    sources = sorted({s for p in pairs if (s := getattr(p.lighting, "source", None)) is not None})
    for source in sources:
        try:
            env = read_envmap(source, sanitize=policy)  # type: ignore[arg-type]
        except NonFiniteError as exc:  # said as the flag, not as the API's `sanitize=` hint
            what = str(exc).split(" Pass `sanitize=")[0]
            raise InputValueError(
                f"{what} Pass `--sanitize zero` (or `clamp`) to repair the dataset's map "
                f"(`--sanitize {policy}` refused it), or fix the file."
            ) from exc
        if policy == "clamp" and not np.array_equal(
            env.radiance_linear, read_envmap(source, sanitize="zero").radiance_linear
        ):
            raise InputValueError(
                f"`{source}` holds +Inf pixels, which `--sanitize clamp` would keep bright but "
                "evaluate's scoring sets to 0; pass `--sanitize zero` or repair the map."
            )


def _reports(args: argparse.Namespace) -> Reports:
    for flag, path in (("--json", args.json), ("--markdown", args.markdown)):
        if path is not None:
            checks.writable_file(flag, path)
    if args.json is not None and args.markdown is not None:
        if args.json.absolute().resolve() == args.markdown.absolute().resolve():
            raise ConfigError(
                f"`--json` and `--markdown` are both {args.json}: one report would replace the "
                "other; pass two file names."
            )
    if args.no_perceptual and args.lpips_backbone is not None:
        raise ConfigError("Pass `--lpips-backbone` or `--no-perceptual`, not both.")
    if args.lpips_backbone is not None:
        checks.need_file("--lpips-backbone", args.lpips_backbone, "torchvision AlexNet weights")
    perceptual = None if args.no_perceptual else (args.lpips_backbone or "auto")
    return Reports(json=args.json, markdown=args.markdown, perceptual=perceptual)


def _read_dir_images(folder: Path, names: Sequence[str], channels: str) -> Any:
    """`[N, C, H, W]` float tensor of the images `names` in `folder`, all of one size."""
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


def _evaluate_folders_request(args: argparse.Namespace, reports: Reports) -> EvaluateFoldersRequest:
    for flag, path in (("--pred", args.pred), ("--gt", args.gt), ("--mask-dir", args.mask_dir)):
        if path is not None:
            checks.need_dir(flag, path, "a folder of images")
    exts = {".png", ".jpg", ".jpeg"}

    def names_in(folder: Path) -> set[str]:
        if not folder.is_dir():
            return set()
        return {p.name for p in folder.iterdir() if p.suffix.lower() in exts}

    gt_names = names_in(args.gt)
    names = sorted(names_in(args.pred) & gt_names)
    if not names:
        raise InputValueError(
            f"No image file names common to `--pred` {args.pred} and `--gt` {args.gt}."
        )
    if len(names) < len(gt_names):
        import logging

        logging.getLogger("gaffer_diffusion.cli").warning(
            "%d ground-truth images have no prediction", len(gt_names) - len(names)
        )
    masks = _read_dir_images(args.mask_dir, names, "L") if args.mask_dir else None
    if masks is not None:  # an all-black mask leaves nothing to score (it used to be scored)
        empty = [n for n, m in zip(names, masks, strict=True) if float(m.max()) <= 0.0]
        if empty:
            shown = ", ".join(empty[:5]) + (", ..." if len(empty) > 5 else "")
            raise InputValueError(
                f"`--mask-dir` {args.mask_dir}: {len(empty)} of {len(names)} masks are all black "
                f"(no object pixel to score): {shown}. Fix or remove them, or drop `--mask-dir` "
                "to score the full frames."
            )
    return EvaluateFoldersRequest(
        pred=args.pred, gt=args.gt, names=tuple(names), masks=masks, reports=reports
    )


def _evaluate_dataset_request(args: argparse.Namespace, reports: Reports) -> EvaluateDatasetRequest:
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
    defaults = _defaults(args)
    object_fraction = _object_fraction_of(args.object_fraction, defaults)
    _check_model_args(args)
    model = _model_choice(args, defaults)
    from gaffer_diffusion.evaluation import dataset_pairs

    pairs = dataset_pairs(
        args.dataset,
        input_lighting=args.input_lighting,
        envmap_dirs=[args.envmaps] if args.envmaps is not None else [],
        limit=args.limit,
    )
    _check_envmaps(pairs, args.sanitize)  # before the model loads
    return EvaluateDatasetRequest(
        dataset=args.dataset,
        pairs=tuple(pairs),
        input_lighting=args.input_lighting,
        model=model,
        object_fraction=object_fraction,
        save_predictions=args.save_predictions,
        reports=reports,
    )


def evaluate_request(args: argparse.Namespace) -> EvaluateRequest:
    """`gaffer-diffusion evaluate`'s arguments as a request of either mode, every refusal first."""
    if args.dataset is not None and (args.pred is not None or args.gt is not None):
        raise ConfigError(
            "Pass either `--dataset DIR --checkpoint CKPT` (relight and score a rendered dataset) or "
            "`--pred DIR --gt DIR` (score existing predictions), not both."
        )
    if args.dataset is None and (args.pred is None or args.gt is None):
        raise ConfigError(
            "Pass `--dataset DIR --checkpoint CKPT`, or both `--pred DIR` and `--gt DIR`."
        )
    reports = _reports(args)
    if args.dataset is None:
        return _evaluate_folders_request(args, reports)
    return _evaluate_dataset_request(args, reports)


# --- insert ---------------------------------------------------------------------------------------


def _key_light(args: argparse.Namespace) -> KeyLight | None:
    """`--key-light`, or the sun of `--sun-at` seen from a camera looking along `--camera-heading`."""
    from gaffer_diffusion.insert_geometry import KeyLight

    sun_at = args.sun_at
    heading = args.camera_heading
    if sun_at is None:
        if heading is not None:
            raise ConfigError("`--camera-heading` goes with `--sun-at LAT,LON,TIME`; pass both.")
        if args.key_light is None:
            return None
        names = ("azimuth_deg", "elevation_deg", "strength", "size_deg")
        return KeyLight(**dict(zip(names, args.key_light, strict=False)))
    if args.key_light is not None:
        raise ConfigError("Pass `--key-light` or `--sun-at`, not both (both place the key light).")
    if heading is None or args.w2c is not None:
        raise ConfigError(
            "`--sun-at` needs `--camera-heading DEG` (the compass bearing the background camera "
            "looks along), and no `--w2c`."
        )
    checks.finite("--camera-heading", heading)
    from gaffer_envmap.sun_position import parse_place, parse_time, sun_position_at

    parts = sun_at.split(",", 2)
    if len(parts) != 3:
        raise ConfigError(
            f"`--sun-at` {sun_at!r} is not LAT,LON,TIME; e.g. 48.86,2.29,2026-06-21T17:00+02:00."
        )
    lat, lon = parse_place(",".join(parts[:2]), "--sun-at")
    sun = sun_position_at(lat, lon, parse_time(parts[2], "--sun-at"))
    if sun.elevation_deg <= 0:
        raise InputValueError(
            f"`--sun-at` {sun_at}: the sun is {-sun.elevation_deg:.1f} degrees below the horizon "
            "then; pass a daytime, or place the light with `--key-light AZ,EL`."
        )
    # the default camera looks along world +y: the sun's bearing relative to the camera's
    return KeyLight(
        azimuth_deg=(sun.azimuth_deg - heading) % 360.0,
        elevation_deg=sun.elevation_deg,
        size_deg=SUN_SIZE_DEG,
    )


def _shown_size(flag: str, path: Path) -> tuple[int, int]:
    """(width, height) of an image as displayed (EXIF orientation 5 to 8 swaps them, as `read_photo`
    and `read_mask` apply it), from its header."""
    w, h = checks.image_size(flag, path)
    from PIL import Image

    try:
        with Image.open(path) as im:
            turned = im.getexif().get(0x0112, 1) in (5, 6, 7, 8)
    except (OSError, ValueError, SyntaxError):
        turned = False
    return (h, w) if turned else (w, h)


def _check_shadow(mode: str) -> None:
    if mode != "cycles":
        return
    if importlib.util.find_spec("bpy") is None:
        raise MissingDependencyError(
            "`--shadow cycles` needs Blender's Python module bpy (pip install "
            '"gaffer-data[render]"), which is not installed; use `--shadow 2d` (the pixel-height '
            "shadow, the default)."
        )


def _light_source(args: argparse.Namespace) -> tuple[Any, dict[str, str]] | None:
    """`--light-source NAME` (a plugin, `gaffer_envmap.sources`): loaded, its capability and options
    checked, and the other lighting flags refused beside it."""
    if args.light_source is None:
        for flag, value in (
            ("--light-text", args.light_text),
            ("--light-source-option", args.light_source_option),
        ):
            if value:
                raise ConfigError(f"`{flag}` goes with `--light-source NAME`; pass both.")
        return None
    for flag, given in (
        ("--envmap", args.envmap is not None),
        ("--light-from-photo", args.light_from_photo),
        ("--key-light", args.key_light is not None),
        ("--sun-at", args.sun_at is not None),
    ):
        if given:
            raise ConfigError(
                f"`--light-source` {args.light_source!r} makes the whole lighting; drop `{flag}` "
                "(or drop --light-source)."
            )
    from gaffer_envmap.sources import load_envmap_source, parse_source_options

    source = load_envmap_source(args.light_source, flag="--light-source")
    if args.light_text is not None and "text" not in source.capabilities:
        raise ConfigError(
            f"`--light-source` {source.name!r} reads the background photo, not words; drop "
            "`--light-text`."
        )
    if args.light_text is None and "photo" not in source.capabilities:
        raise ConfigError(
            f"`--light-source` {source.name!r} turns words into lighting; pass `--light-text "
            'PHRASE` (e.g. "golden hour from the left").'
        )
    if args.light_text is None and args.w2c is not None:
        raise ConfigError(
            f"`--w2c`: the map `--light-source` {source.name!r} estimates from the photo is in the "
            "background camera's own frame; drop --w2c."
        )
    return source, parse_source_options(
        args.light_source_option, source, flag="--light-source-option"
    )


def _insert_lighting(
    args: argparse.Namespace,
    background: Photo,
    envmap: Any,
    w2c: Any,
    key: KeyLight | None,
    light_source: tuple[Any, dict[str, str]] | None,
) -> InsertLighting:
    """The background's lighting: `--envmap` (read), the plugin of `--light-source`, or the map built
    from the photo (`--light-from-photo`, the default) with its key light."""
    from gaffer_diffusion.insert_geometry import (
        LEVEL_CAMERA,
        BackgroundCamera,
        InsertLighting,
        light_from_photo,
    )

    w, h = background.size_wh
    camera = BackgroundCamera(width=w, height=h, fov_deg=args.fov, w2c=w2c if w2c else LEVEL_CAMERA)
    if envmap is not None:
        return InsertLighting(
            envmap=envmap, camera=camera, source=f"lighting: --envmap {args.envmap}"
        )
    if light_source is not None:
        return _lighting_from_source(args, light_source, background, camera)
    source = "lighting: the background wrapped onto the sphere (--light-from-photo) + " + (
        f"{'the sun of --sun-at' if args.sun_at else 'a key light'} {key.describe('.1f')}"
        if key is not None
        else "no key light: the photo rarely shows its key light; give it with `--key-light AZ,EL`"
    )
    env = light_from_photo(background.rgb, camera, key)
    return InsertLighting(envmap=env, camera=camera, key_light=key, source=source)


def _lighting_from_source(
    args: argparse.Namespace,
    light_source: tuple[Any, dict[str, str]],
    background: Photo,
    camera: BackgroundCamera,
) -> InsertLighting:
    """The map of `--light-source`: from `--light-text`, or estimated from the background photo."""
    from gaffer_diffusion.insert_geometry import LIGHT_FROM_PHOTO_WIDTH, InsertLighting
    from gaffer_envmap.sources import envmap_from_photo, envmap_from_text

    source, options = light_source
    common = {
        "width": LIGHT_FROM_PHOTO_WIDTH,
        "options": options,
        "policy": args.sanitize,
        "flag": "--light-source",
    }
    if args.light_text is not None:
        env = envmap_from_text(source, args.light_text, **common)
        what = f"--light-text {args.light_text!r}"
    else:
        env = envmap_from_photo(source, background.rgb, fov_deg=args.fov, **common)
        what = f"the background photo at --fov {args.fov:g}"
    note = env.metadata.get("gaffer:source_note")
    return InsertLighting(
        envmap=env,
        camera=camera,
        source=f"lighting: --light-source {source.name} from {what}"
        + (f" ({note})" if note else ""),
    )


def insert_request(args: argparse.Namespace) -> InsertRequest:
    """`gaffer-diffusion insert`'s arguments as a request: every flag and file checked, the map and
    `--w2c` read, then both photos, the placement and the lighting, before any weights load."""
    from gaffer_envmap.poses import W2CBlender

    ow, oh = _shown_size("OBJECT", args.object)
    bw, bh = _shown_size("--into", args.into)
    if isinstance(args.mask, Path):
        mw, mh = _shown_size("--mask", args.mask)
        if (mw, mh) != (ow, oh):
            raise InputValueError(
                f"`--mask` {args.mask} is {mw}x{mh} but OBJECT {args.object} is {ow}x{oh} (width x "
                "height); pass the object photo's mask, of its size (white = object), or "
                "`--mask auto`."
            )
    _check_photo_flags(args)
    checks.finite("--fov", args.fov, 1.0, 179.0)
    if args.height is not None:
        checks.finite("--height", args.height, 0.0, lo_open=True)
    if args.at is not None:
        x, y = args.at
        if not (math.isfinite(x) and math.isfinite(y) and 0 <= x < bw and 0 <= y < bh):
            raise InputValueError(
                f"`--at` {x:g},{y:g} is outside the background ({bw}x{bh}): pass X in "
                f"[0, {bw - 1}] and Y in [0, {bh - 1}], pixels from the top-left."
            )
    _check_shadow(args.shadow)
    if args.envmap is not None and args.light_from_photo:
        raise ConfigError(
            "Pass `--envmap` (a map you have) or `--light-from-photo` (the map built from the "
            "background), not both."
        )
    if args.envmap is not None and (args.key_light is not None or args.sun_at is not None):
        flag = "--key-light" if args.key_light is not None else "--sun-at"
        raise ConfigError(
            f"`{flag}` adds a key light to the map built from the background "
            "(`--light-from-photo`); an `--envmap` brings its own light. Drop one of them."
        )
    envmap = None
    if args.envmap is not None:
        _check_envmap_arg(args.envmap)
        envmap = _read_envmap(
            args.envmap, args.sanitize
        )  # decoded now: an unreadable map fails here
    w2c = W2CBlender.from_array(_read_w2c(args.w2c)) if args.w2c is not None else None
    light_source = _light_source(args)
    key = _key_light(args)
    _check_sampling_args(args)
    _check_model_args(args)
    inputs = [
        ("OBJECT", args.object),
        ("--into", args.into),
        ("--mask", args.mask),
        ("--envmap", args.envmap),
        ("--w2c", args.w2c),
    ]
    siblings = [] if isinstance(args.mask, Path) else [_mask_out(args.out)]
    checks.writable_file("--out", args.out, siblings=siblings, suffixes=(".png",))
    checks.not_an_input("--out", args.out, inputs)
    if args.save_envmap is not None:
        from gaffer_envmap.io import check_write_suffix

        check_write_suffix(args.save_envmap, "--save-envmap")
        checks.writable_file("--save-envmap", args.save_envmap)
        checks.not_an_input("--save-envmap", args.save_envmap, [*inputs, ("--out", args.out)])
    model = _model_choice(args)
    read = _photo_and_mask(None, args.object, args.mask, _mask_out(args.out))
    from gaffer_diffusion.insert_geometry import object_extent, resolve_placement
    from gaffer_diffusion.photo import read_photo

    background = read_photo(args.into)
    placement = resolve_placement(  # --at / --height refused before weights
        background.size_wh, object_extent(read.alpha), at_xy=args.at, height_px=args.height
    )
    return InsertRequest(
        object=read,
        background=background,
        placement=placement,
        lighting=_insert_lighting(args, background, envmap, w2c, key, light_source),
        model=model,
        out=args.out,
        save_envmap=args.save_envmap,
        shadow=args.shadow,
        detail=args.detail,
    )
