"""The argparse parser of `gaffer-diffusion`: every subcommand, flag and help text, and the small
argument types the flags use (`--mask`, `--envmap`, `--input-lighting`). No torch: building the parser
and checking what it parsed come before any model loads (a refusal takes a fraction of a second)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, get_args

from gaffer_diffusion._choices import (
    BACKDROP_FOV_DEG,
    PRESETS,
    SCHEDULERS,
    Background,
    DetailMode,
    LatentMode,
    OutputSize,
    PrepareCompat,
    ShadowMode,
)
from gaffer_diffusion.app.config import add_app_arguments
from gaffer_diffusion.cli.insert import parse_key_light, parse_xy
from gaffer_diffusion.runtime_dtype import DTYPE_REQUESTS
from gaffer_envmap.cli_sky import add_source_arguments
from gaffer_envmap.cli_support import add_debug_argument, exit_codes_epilog
from gaffer_envmap.compat_mode import COMPAT_MODES
from gaffer_envmap.sanitize import add_sanitize_argument

_DESCRIPTION = "Command line: `gaffer-diffusion demo | relight | evaluate | init-random | train`."
"""The first paragraph of `gaffer_diffusion.cli`'s docstring, shown atop `--help`."""

EXIT_CODES = {
    0: "done",
    1: "`relight` on a folder wrote some images but others failed (listed on stderr)",
    2: "refused or failed (one stderr line naming the argument and the fix)",
    130: "interrupted (Ctrl-C; train: --resume continues from the last checkpoint)",
}
"""What `gaffer_diffusion.cli.main` returns (documented in `--help` and docs/cli.md)."""


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="gaffer-diffusion", description=_DESCRIPTION, epilog=exit_codes_epilog(EXIT_CODES)
    )
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("relight", help="relight one object image under an environment map")
    r.add_argument("image", type=Path, help=f"{_IMAGE_HELP}; or a folder of them")
    r.add_argument(
        "--mask",
        type=_mask_arg,
        help=f"{_MASK_HELP}; a folder of masks with the images' file names when IMAGE is a folder",
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
        choices=COMPAT_MODES,
        default=None,
        help="lighting encoding; 'neural-gaffer' matches the released checkpoint (the default with "
        "--checkpoint); without one, gaffer-tiny's own ('default')",
    )
    add_sanitize_argument(light)
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
    add_sanitize_argument(ds)
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
        choices=COMPAT_MODES,
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
        choices=COMPAT_MODES,
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
    add_sanitize_argument(
        d, what="the --example's maps (the bundled HDRIs are read as gaffer-envmap ships them): "
    )

    _add_insert_command(sub)
    _add_authors_commands(sub)
    _add_normals_commands(sub)

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
    x.add_argument(
        "--half",
        action="store_true",
        help="store the UNet's weights as float16 (half the file; loaded back as float32)",
    )

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
    add_debug_argument(p)
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
        help="sampler (default: ddim, the paper's, also under --compat neural-gaffer); dpmpp-2m "
        "(DPM-Solver++ 2M; dpmsolver++ is its earlier name) or unipc reach DDIM 50's result in "
        "15-25 --steps",
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
        choices=DTYPE_REQUESTS,
        default="auto",
        help="networks' precision (default: auto: bfloat16 on a CPU with native bf16, AMX-BF16 or "
        "AVX512-BF16, for a model of 100M+ UNet parameters, else float32; the output line names it)",
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


_IMAGE_HELP = (
    "object photo: its alpha is the object mask; without one (RGB, JPEG, or an all-opaque alpha) "
    "the mask is estimated (GrabCut, as --mask auto) and written beside the output as OUT.mask.png"
)
"""The photo argument of `relight`, `normals` and `prepare` (an estimated mask is one of the outputs)."""

_MASK_HELP = (
    "object mask (white = object), used instead of the photo's alpha; 'auto': a classical GrabCut "
    "estimate (offline, no weights) even when the photo has an alpha, written beside the output as "
    "OUT.mask.png"
)
"""The `--mask` flag of `relight`, `normals` and `prepare`."""


def _mask_arg(text: str) -> Path | str:
    """`--mask`: a path, or 'auto' (GrabCut)."""
    return "auto" if text == "auto" else Path(text)


def _envmap_path(value: str) -> Path:
    """`--envmap`: a file, or the name of an HDRI bundled with gaffer-envmap (`city`, `studio`, ...)."""
    path = Path(value)
    if path.exists() or path.suffix:
        return path
    from gaffer_envmap.bundled import bundled_hdris

    return bundled_hdris().get(value, path)


def _add_normals_commands(sub: Any) -> None:
    """`normals` and `train-normals`: the learned normal estimator alone, and its training."""
    nm = sub.add_parser(
        "normals",
        help="estimate camera-frame normals of a photo's object (the geometry gaffer-tiny's hints use)",
    )
    nm.add_argument("image", type=Path, help=_IMAGE_HELP)
    nm.add_argument("--mask", type=_mask_arg, help=_MASK_HELP)
    nm.add_argument(
        "--out", type=Path, required=True, help="output PNG: RGB = (n + 1) / 2, white outside"
    )
    nm.add_argument(
        "--output-size",
        choices=("input", "model"),
        default="input",
        help="'input' (default): at the photo's size and place; 'model': the estimator's square crop",
    )
    nm.add_argument(
        "--estimator", type=Path, help="an estimator folder (default: the shipped gaffer-normals)"
    )
    tn = sub.add_parser(
        "train-normals",
        help="train the normal estimator on gaffer-data renders' normal passes (extra [train])",
    )
    tn.add_argument(
        "--data",
        type=Path,
        required=True,
        action="append",
        help="training renders (repeat for several folders; their views are pooled)",
    )
    tn.add_argument(
        "--init",
        type=Path,
        help="an estimator folder to continue from (its shapes are kept); default: from scratch",
    )
    tn.add_argument(
        "--widths",
        help="channels of the UNet's levels when training from scratch, comma-separated (default "
        "16,32,64,96, gaffer-normals' own); not with --init, whose shapes are kept",
    )
    tn.add_argument(
        "--lr", type=float, default=2e-3, help="peak learning rate (2e-3; less to fine-tune)"
    )
    tn.add_argument("--val", type=Path, help="held-out renders: angular error vs the dome")
    tn.add_argument("--out", type=Path, required=True, help="estimator folder to write")
    tn.add_argument("--minutes", type=float, default=15.0, help="training time budget (15)")
    tn.add_argument(
        "--steps",
        type=int,
        default=4000,
        help="step budget (4000); the learning rate decays over it, so a run that ends on its step "
        "budget ends fully decayed",
    )
    tn.add_argument("--seed", type=int, default=0, help="seed (0)")
    tn.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")


def _add_authors_commands(sub: Any) -> None:
    """`prepare` and `check`: what the model sees, and whether the authors' files are complete."""
    pr = sub.add_parser(
        "prepare", help="write the model-ready square input (on white) and its mask, as PNGs"
    )
    pr.add_argument("image", type=Path, help=_IMAGE_HELP)
    pr.add_argument("--mask", type=_mask_arg, help=_MASK_HELP)
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


def _add_insert_command(sub: Any) -> None:
    """`insert`: an object photo relit and placed into a background photo, with a shadow."""
    n = sub.add_parser(
        "insert",
        help="relight an object photo under a background's lighting and paste it in, with a shadow",
    )
    n.add_argument("object", type=Path, metavar="OBJECT", help=_IMAGE_HELP)
    n.add_argument("--into", type=Path, required=True, help="the background photo (PNG/JPEG/WebP)")
    n.add_argument("--out", type=Path, required=True, help="output PNG, the background's size")
    n.add_argument("--mask", type=_mask_arg, help=_MASK_HELP)
    n.add_argument(
        "--at",
        type=parse_xy,
        metavar="X,Y",
        help="background pixel (column,row from the top-left) of the object's lowest centre point "
        "(default: the centre of the bottom third of the frame)",
    )
    n.add_argument(
        "--height",
        type=float,
        help="the object's height in background pixels (default: its height in OBJECT)",
    )
    n.add_argument(
        "--fov",
        type=float,
        default=BACKDROP_FOV_DEG,
        help=f"the background's horizontal field of view, degrees (default {BACKDROP_FOV_DEG})",
    )
    light = n.add_argument_group(
        "lighting: --envmap (with the background camera's --w2c), --light-from-photo (default) or "
        "--light-source NAME (a plugin: a light-estimation or text-to-HDR model)"
    )
    light.add_argument(
        "--envmap",
        type=_envmap_path,
        help="the background's HDR map (.exr/.hdr, Blender z-up) or a bundled HDRI's name",
    )
    light.add_argument(
        "--w2c",
        type=Path,
        help="the background camera's 3x4/4x4 Blender world-to-camera .npy (default: level, "
        "looking along world +y)",
    )
    light.add_argument(
        "--light-from-photo",
        action="store_true",
        help="build the map from the background (the default without --envmap): the photo wrapped "
        "onto the sphere at --fov, the rest a blurred mirrored extension, expanded to HDR; its key "
        "light is mostly outside the frame, so give it with --key-light",
    )
    light.add_argument(
        "--key-light",
        type=parse_key_light,
        metavar="AZ,EL[,STRENGTH[,SIZE_DEG]]",
        help="a key light added to the map from the photo as a disc of exact power: azimuth degrees "
        "clockwise from world +y seen from above (default camera: 0 straight ahead, behind the "
        "object; 90 from the right; 180 from behind the camera), elevation degrees; STRENGTH its "
        "irradiance in multiples of the photo's mean light (default 3), SIZE_DEG its angular "
        "diameter (default 5). Give it: the photo rarely shows its key light",
    )
    light.add_argument(
        "--sun-at",
        metavar="LAT,LON,TIME",
        help="the key light is the sun seen from this place at this time (decimal degrees, north and "
        "east positive; ISO 8601 with a UTC offset, e.g. 48.86,2.29,2026-06-21T17:00+02:00; needs "
        'astral: pip install "gaffer-envmap[sky]"), with --camera-heading',
    )
    light.add_argument(
        "--camera-heading",
        type=float,
        help="with --sun-at: the compass bearing the background camera looks along, degrees "
        "clockwise from north (0 north, 90 east)",
    )
    add_source_arguments(light, prefix="light-")
    light.add_argument(
        "--light-text",
        metavar="PHRASE",
        help="with --light-source: the words it turns into the lighting (e.g. --light-source sky "
        '--light-text "golden hour from the left"); without it a light-estimation source reads '
        "the background photo",
    )
    light.add_argument(
        "--save-envmap", type=Path, help="write the lighting used here (.exr, Blender convention)"
    )
    light.add_argument(
        "--compat",
        choices=COMPAT_MODES,
        default=None,
        help="lighting encoding (default: the model's own; gaffer-tiny: 'default')",
    )
    add_sanitize_argument(light)
    n.add_argument(
        "--shadow",
        choices=get_args(ShadowMode),
        default="2d",
        help="'2d' (default): a pixel-height soft shadow cast on the ground from the mask, away "
        "from the dominant light; 'cycles': Blender Cycles' shadow catcher under the same map, from "
        "a proxy inflated from the mask (needs bpy; about 3-6 s); 'none'",
    )
    n.add_argument(
        "--detail",
        choices=get_args(DetailMode),
        default="transfer",
        help="'transfer' (default): the model's change of shading applied to the full-resolution "
        "object photo; 'resize': the model's output upsampled",
    )
    n.add_argument(
        "--checkpoint",
        type=Path,
        help="our model folder or checkpoint-80000/ (default: gaffer-tiny, shipped, 128 px)",
    )
    n.add_argument("--base-model", type=Path, help="Zero-1-to-3 XL folder (authors' checkpoint)")
    _add_sampling_args(n)
