"""Command line: `gaffer-nerf fit | relight | render | evaluate`.

    gaffer-nerf fit DATA --out FIELD [--preset paper|tiny] [--iterations N] [--lighting-index 0]
        [--sizing fixed|footprint] [--early-stopping] [--rank-selection [--rank-ladder 0.25 0.5 1]
        [--rank-tolerance DB]] [--device cuda]
    gaffer-nerf relight FIELD --data DATA --target-lighting K [--envmaps DIR | --envmap FILE|NAME]
        [--sanitize raise|strict|zero|clamp] [--checkpoint CKPT [--base-model DIR] | --diffusion-preset tiny]
        --out RELIT [--preset paper|tiny (default: the fit's)] [--ablation full|no-stage1|no-stage2|sds-stage2|sds-only]
        [--t-schedule exponential|authors] [--stage1-iterations N] [--stage2-iterations N]
        [--stage1-detail model|transfer [--stage1-transfer-radius R]]
        [--steps N] [--scheduler ddim|dpmpp-2m|unipc] [--dtype auto|float32|bfloat16|float16]
        [--guidance S] [--average-samples K] [--[no-]mirror-average] [--compat C]
        [--[no-]shared-noise] [--object-fraction F|whole]
    gaffer-nerf render FIELD --data DATA [--split test | --orbit N [--fps 12]] --out DIR
    gaffer-nerf evaluate FIELD --data DATA --target-lighting K [--split test] [--json F]

DATA is a gaffer-data multi-view object folder or a NeRF-Synthetic scene (`transforms_*.json`).
FIELD is a folder written by `fit` / `relight` (`config.json` + `field.safetensors`).
Without `--checkpoint`, `relight` uses gaffer-tiny, the 128 px model shipped with gaffer-diffusion
(as `gaffer-diffusion relight` does), and says so. Every stage samples the model with its own
suggested setting (gaffer-tiny: 1 step, guidance 1, mirror average, "default" encoding; the authors'
release: the paper's 50 steps, guidance 3) unless `--steps`, `--guidance`, `--average-samples`,
`--mirror-average` or `--compat` say otherwise, and sees each training view framed as it was trained
(gaffer-tiny: an object-centred square in which the object spans 0.75) unless `--object-fraction` does.
`--diffusion-preset tiny` uses a RANDOM tiny model: for smoke tests only, its relighting is noise.

Every command checks its arguments first (files exist and parse, numbers in range, outputs writable;
`gaffer_nerf.preflight`), before torch is imported or a model loaded, so a refusal takes well under a
second and leaves nothing behind. Exit codes: 0 done, 2 refused or failed (one line on stderr),
130 Ctrl-C; 1 only for an unexpected internal error (a bug: Python prints its traceback). `--debug`
also prints the traceback of an expected failure.
"""

import argparse
import dataclasses
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gaffer_envmap.cli_support import (
    add_debug_argument,
    cli_failure,
    exit_codes_epilog,
    output_path,
)
from gaffer_envmap.compat_mode import COMPAT_MODES
from gaffer_envmap.sanitize import add_sanitize_argument, sanitize_flag_refusal
from gaffer_nerf import preflight
from gaffer_nerf.configs import (
    ABLATIONS,
    SAMPLER_LABELS,
    SAMPLERS,
    EarlyStoppingConfig,
    PresetName,
    RankSelectionConfig,
    fit_preset,
    relight_preset,
)
from gaffer_nerf.errors import ConfigError, GafferNerfError

DTYPES = ("auto", "float32", "bfloat16", "float16")
"""`relight --dtype`: gaffer-diffusion's `RuntimeConfig.dtype` values (checked again there)."""

if TYPE_CHECKING:  # torch and the field code are imported only once the arguments are checked
    from gaffer_nerf.data.transforms import MultiViewScene, ViewSet

logger = logging.getLogger(__name__)

EXIT_CODES = {
    0: "done",
    2: "refused or failed (one stderr line naming the argument and the fix)",
    130: "interrupted (Ctrl-C)",
    1: "an unexpected internal error (a bug; Python prints the traceback)",
}
"""What `main` returns (documented in `--help` and docs/cli.md)."""


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="gaffer-nerf",
        description=(__doc__ or "").split("\n\n")[0],
        epilog=exit_codes_epilog(EXIT_CODES),
    )
    sub = p.add_subparsers(dest="command", required=True)

    f = sub.add_parser("fit", help="fit a TensoRF field to the input-lighting views")
    f.add_argument("data", type=Path, help="multi-view folder with transforms_train.json")
    f.add_argument("--out", type=output_path, required=True, help="output field folder")
    f.add_argument(
        "--preset",
        choices=("paper", "tiny"),
        default="paper",
        help="paper: TensoRF's schedule (30K iterations x 4096 rays); tiny: a seconds-long smoke fit",
    )
    f.add_argument("--iterations", type=int, help="override the preset's iteration count")
    f.add_argument("--batch-rays", type=int, help="override the rays per step")
    f.add_argument("--lighting-index", type=int, default=0, help="gaffer-data lighting to fit (0)")
    f.add_argument("--plain", action="store_true", help="NeRF-Synthetic folder: load file_path")
    f.add_argument(
        "--sizing",
        choices=("fixed", "footprint"),
        default="fixed",
        help="grid size: the preset's fixed one, or chosen from the cameras' pixel footprint and "
        "capped by the iteration budget (default: fixed)",
    )
    f.add_argument("--early-stopping", action="store_true", help="stop on a held-out PSNR plateau")
    f.add_argument(
        "--rank-selection",
        action="store_true",
        help="fit a ladder of VM ranks and keep the smallest the held-out PSNR justifies",
    )
    f.add_argument(
        "--rank-ladder",
        type=float,
        nargs="+",
        metavar="SCALE",
        help="rank multipliers of the ladder, small first (0.25 0.5 1.0)",
    )
    f.add_argument(
        "--rank-tolerance", type=float, metavar="DB", help="gain a larger rung must beat (0.25)"
    )
    f.add_argument("--seed", type=int, default=0, help="seed of the ray batches and init (0)")

    r = sub.add_parser("relight", help="relight a fitted field under a target lighting")
    r.add_argument("field", type=Path, help="field folder from `fit`")
    r.add_argument("--data", type=Path, required=True, help="the multi-view folder it was fit to")
    r.add_argument("--input-lighting", type=int, default=0, help="lighting of the inputs (0)")
    r.add_argument("--target-lighting", type=int, help="gaffer-data lighting index to relight to")
    r.add_argument(
        "--envmap",
        help="target env map: a file (.exr/.hdr), or a bundled HDRI name (city, courtyard, forest, "
        "...), instead of --target-lighting",
    )
    r.add_argument("--envmaps", type=Path, help="folder holding the pool's env maps")
    add_sanitize_argument(r)
    r.add_argument(
        "--checkpoint",
        type=Path,
        help="diffusion model: our folder or checkpoint-80000/ (default: gaffer-tiny, shipped, 128 px)",
    )
    r.add_argument("--base-model", type=Path, help="Zero-1-to-3 XL folder (authors' checkpoint)")
    r.add_argument("--diffusion-preset", choices=("tiny",), help="random tiny model (smoke tests)")
    r.add_argument(
        "--out", type=output_path, required=True, help="output folder (relit field + report)"
    )
    r.add_argument(
        "--preset",
        choices=("paper", "tiny"),
        default=None,
        help="paper: Stage 1 2,500 + Stage 2 500 iterations (section 3.4); tiny: 100 + 6 at small "
        "learning rates, for small fields (default: the preset the field was fitted with, recorded "
        "in its fit_report.json; paper when none is recorded)",
    )
    r.add_argument(
        "--ablation",
        choices=ABLATIONS,
        default=None,
        help="paper section 4.4: full, without Stage 1 or 2, SDS in Stage 2, or SDS only (default: "
        "full, without Stage 2 for a model that samples in one step, such as gaffer-tiny)",
    )
    r.add_argument(
        "--t-schedule",
        choices=("exponential", "authors"),
        default="exponential",
        help="Stage 2 noise level t*: the paper's exponential 0.4 -> 0.05, or the authors' "
        "effectively constant one (default: exponential)",
    )
    r.add_argument("--stage1-iterations", type=int, help="override the preset's Stage 1 iterations")
    r.add_argument("--stage2-iterations", type=int, help="override the preset's Stage 2 iterations")
    r.add_argument(
        "--stage1-detail",
        choices=("model", "transfer"),
        help="Stage 1 fits the relit views as the model made them (model: the paper) or the input "
        "views times the model's change of shading, keeping their texture (transfer) "
        "(default: the preset's)",
    )
    r.add_argument(
        "--stage1-transfer-radius",
        type=int,
        help="box half-width in view pixels the shading change is averaged over with "
        "--stage1-detail transfer (default: the preset's)",
    )
    r.add_argument(
        "--steps",
        type=int,
        help="sampler steps of the full schedule (default: the model's suggestion)",
    )
    r.add_argument(
        "--scheduler",
        choices=SAMPLERS,
        default=None,
        help="sampler of the relit views and Stage 2's targets: ddim (the paper, default) or the "
        "multistep dpmpp-2m / unipc, for 15-25 --steps",
    )
    r.add_argument(
        "--dtype",
        choices=DTYPES,
        default=None,
        help="precision of the diffusion model (default: auto on a CPU, bfloat16 where it has "
        "native bf16 and the model is large, else float32; float16 on CUDA)",
    )
    r.add_argument(
        "--guidance", type=float, help="CFG scale, also of SDS (default: the model's suggestion)"
    )
    r.add_argument(
        "--average-samples",
        type=int,
        default=None,
        help="mean of K samples per relit view / target (default: the model's suggestion)",
    )
    r.add_argument(
        "--mirror-average",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="average with the view mirrored left-right under the mirrored lighting (2x the cost; "
        "default: the model's suggestion, gaffer-tiny: on)",
    )
    r.add_argument(
        "--shared-noise",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="start every view's relighting from the same noise (default: per-view noise; one "
        "shared noise gives every view the same sample's colour error, which the field cannot "
        "average away)",
    )
    r.add_argument(
        "--object-fraction",
        type=_fraction_or_whole,
        default=None,
        metavar="F|whole",
        help="show the model object-centred square crops in which the object spans F of the side, "
        "or 'whole' views (default: the model's framing, gaffer-tiny: 0.75)",
    )
    r.add_argument(
        "--compat",
        choices=COMPAT_MODES,
        default=None,
        help="lighting encoding (default: the model's own; 'neural-gaffer' for the released "
        "checkpoint, 'default' for gaffer-tiny)",
    )
    r.add_argument("--lpips-backbone", type=Path, help="torchvision AlexNet weights (std LPIPS)")

    d = sub.add_parser("render", help="render a field at the poses of a split")
    d.add_argument("field", type=Path, help="field folder from `fit` or `relight`")
    d.add_argument("--data", type=Path, required=True, help="the multi-view folder (cameras)")
    d.add_argument(
        "--split", choices=("train", "test"), default="test", help="which cameras (default: test)"
    )
    d.add_argument("--out", type=output_path, required=True, help="folder for the PNGs")
    d.add_argument(
        "--orbit",
        type=int,
        metavar="N",
        help="instead of the split's poses, N frames on an orbit like its cameras + orbit.gif",
    )
    d.add_argument("--fps", type=float, default=12.0, help="frame rate of orbit.gif (12)")

    e = sub.add_parser(
        "evaluate", help="score renders against ground truth under the target lighting"
    )
    e.add_argument("field", type=Path, help="field folder from `fit` or `relight`")
    e.add_argument(
        "--data", type=Path, required=True, help="the multi-view folder with the ground truth"
    )
    e.add_argument("--target-lighting", type=int, help="lighting of the ground truth")
    e.add_argument("--plain", action="store_true", help="NeRF-Synthetic folder: load file_path")
    e.add_argument(
        "--split", choices=("train", "test"), default="test", help="views scored (default: test)"
    )
    e.add_argument("--json", type=output_path, help="write the report as JSON")
    e.add_argument(
        "--flicker",
        action="store_true",
        help="also score the flicker along the split's views in file order (a camera path, e.g. "
        "gaffer-data's `--layout orbit`): mean |frame-to-frame change of the renders - that of the "
        "ground truth| in the object mask (gaffer_nerf.flicker)",
    )
    e.add_argument("--pred-dir", type=output_path, help="also write the renders as PNGs here")
    e.add_argument("--lpips-backbone", type=Path, help="torchvision AlexNet weights (std LPIPS)")

    for sp in (f, r, d, e):
        sp.add_argument(
            "--device",
            default="auto",
            help="torch device: auto (cuda when available, else cpu; the default), cpu, cuda[:N], mps",
        )
        sp.add_argument("--no-progress", action="store_true", help="hide progress bars")
    add_debug_argument(p)
    return p


def _scene(data: Path, lighting: int | None) -> "MultiViewScene":
    from gaffer_nerf.data import read_gaffer_data_object, read_transforms_folder

    if lighting is None:
        return read_transforms_folder(data)
    return read_gaffer_data_object(data, lighting_index=lighting)


def _split(scene: "MultiViewScene", split: str) -> "ViewSet":
    views = scene.train if split == "train" else scene.test
    if views is None:
        raise ConfigError(f"{scene.root} has no `transforms_{split}.json`; pick --split train.")
    return views


def _jsonable(obj: Any) -> Any:
    import torch

    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {k: _jsonable(v) for k, v in dataclasses.asdict(obj).items()}
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, torch.Tensor):
        return obj.tolist()
    if isinstance(obj, float) and obj != obj:
        return "nan"
    return obj


def _fit(args: argparse.Namespace) -> int:
    cfg = _fit_config(args)  # every check before torch is imported
    info = preflight.check_data_folder(args.data)
    if not args.plain:
        preflight.check_lighting(info, "--lighting-index", args.lighting_index)
    if (cfg.early_stopping is not None or cfg.rank_selection is not None) and not info.has_test:
        raise ConfigError(
            f"`--early-stopping` / `--rank-selection` score held-out views, but {args.data} has no "
            "`transforms_test.json`; add a test split or drop those flags."
        )
    preflight.check_output_dir(args.out, "--out", files=(*preflight.FIELD_FILES, "fit_report.json"))
    preflight.check_device_name(args.device)
    device = preflight.resolve_device(args.device)

    from gaffer_nerf.checkpoint import save_field
    from gaffer_nerf.fit import fit_tensorf

    logger.info("loading %s (%d train views)", args.data, info.train_frames)
    scene = _scene(args.data, None if args.plain else args.lighting_index)
    heldout = scene.test if cfg.early_stopping or cfg.rank_selection is not None else None
    res = fit_tensorf(
        scene.train, cfg, heldout=heldout, device=device, progress=not args.no_progress
    )
    # the field and its report: all three files or none (a killed save leaves the old set)
    # the preset goes with the field: `relight` takes its own from it
    report = json.dumps({"preset": args.preset, **_jsonable(res.report)}, indent=2)
    save_field(res.field, args.out, extra={"fit_report.json": report})
    rep = res.report
    print(
        f"fit: {rep.iterations_run} iterations in {rep.seconds:.1f} s, grid "
        f"{'x'.join(map(str, rep.final_grid))} ({rep.grid_bytes / 2**20:.1f} MiB), "
        f"last batch MSE {rep.final_train_loss:.3g} -> {args.out}"
    )
    if rep.rank_selection is not None:
        for k, rung in enumerate(rep.rank_selection.rungs):
            mark = "*" if k == rep.rank_selection.chosen else " "
            print(
                f" {mark} ranks {rung.density_ranks} / {rung.appearance_ranks}: "
                f"{rung.heldout_psnr:.2f} dB held out, {rung.parameters} parameters "
                f"({rung.memory_mib:.2f} MiB), {rung.seconds:.1f} s"
            )
    return 0


def _fit_config(args: argparse.Namespace) -> Any:
    """The preset with the command line's overrides (torch-free; a bad number fails here)."""
    preflight.check_count(args.iterations, "--iterations")
    if args.batch_rays is not None:
        preflight.check_batch_rays(args.batch_rays)
    cfg = fit_preset(args.preset)
    changes: dict[str, Any] = {"seed": args.seed}
    if args.iterations is not None:
        changes["iterations"] = args.iterations
    if args.batch_rays is not None:
        changes["batch_rays"] = args.batch_rays
    changes["sizing"] = dataclasses.replace(cfg.sizing, mode=args.sizing)
    if args.early_stopping:
        changes["early_stopping"] = EarlyStoppingConfig()
    selecting = (
        args.rank_selection or args.rank_ladder is not None or args.rank_tolerance is not None
    )
    if selecting:
        sel: dict[str, Any] = {}
        if args.rank_ladder is not None:
            sel["ladder"] = tuple(args.rank_ladder)
        if args.rank_tolerance is not None:
            sel["tolerance_db"] = args.rank_tolerance
        try:
            changes["rank_selection"] = RankSelectionConfig(**sel)
        except ConfigError as exc:
            raise ConfigError(f"`--rank-ladder` / `--rank-tolerance`: {exc}") from exc
    return dataclasses.replace(cfg, **changes)


def _load_diffusion(args: argparse.Namespace, runtime: Any = None) -> Any:
    """The relighting model (`--checkpoint`, else gaffer-tiny, or the random smoke model)."""
    from gaffer_nerf.guidance.model import load_relighting_model

    return load_relighting_model(
        args.checkpoint, args.base_model, smoke=args.diffusion_preset == "tiny", runtime=runtime
    )


def _relight_config(args: argparse.Namespace) -> Any:
    """The preset with the command line's overrides (validated: a bad flag fails here, early)."""
    cfg = relight_preset(_relight_preset_name(args)[0], args.ablation or "full")
    for flag, value in (
        ("--stage1-iterations", args.stage1_iterations),
        ("--stage2-iterations", args.stage2_iterations),
    ):
        if value is not None and value < 1:
            raise ConfigError(f"`{flag}` is {value}; expected an int >= 1 (leave it out: preset).")
    if args.stage1_transfer_radius is not None and args.stage1_transfer_radius < 0:
        raise ConfigError(
            f"`--stage1-transfer-radius` is {args.stage1_transfer_radius}; expected an int >= 0 "
            "(0: the shading change pixel by pixel)."
        )
    if cfg.stage1 is not None:
        s1_over: dict[str, Any] = {
            k: v
            for k, v in (
                ("iterations", args.stage1_iterations),
                ("target_detail", args.stage1_detail),
                ("transfer_radius_px", args.stage1_transfer_radius),
            )
            if v is not None
        }
        cfg = dataclasses.replace(cfg, stage1=dataclasses.replace(cfg.stage1, **s1_over))
    if cfg.stage2 is not None:
        s2 = dataclasses.replace(cfg.stage2, t_schedule=args.t_schedule)
        if args.stage2_iterations is not None:
            s2 = dataclasses.replace(s2, iterations=args.stage2_iterations)
        cfg = dataclasses.replace(cfg, stage2=s2)
    overrides = {
        "num_inference_steps": args.steps,
        "scheduler": args.scheduler,
        "guidance_scale": args.guidance,
        "average_samples": args.average_samples,
        "mirror_average": args.mirror_average,
        "compat": args.compat,
        "object_fraction": args.object_fraction,
    }
    given = {k: v for k, v in overrides.items() if v is not None}
    if args.shared_noise is not None:
        given["shared_noise"] = args.shared_noise
    if given:  # DiffusionSamplingConfig refuses bad values naming the flag
        cfg = dataclasses.replace(cfg, diffusion=dataclasses.replace(cfg.diffusion, **given))
    return cfg


def _relight_preset_name(args: argparse.Namespace) -> tuple[PresetName, str, str | None]:
    """`relight`'s preset, why, and the fit's preset to record: `--preset`, else the field's fit's.

    A tiny field relit with the paper's 2,500 + 500 steps at the paper's learning rates took 11
    minutes and whitened the object; a field takes the preset it was fitted with.
    """
    recorded = preflight.read_field_preset(args.field)
    if args.preset is not None:
        return args.preset, "--preset", recorded.name
    if recorded.name == "paper" or recorded.name == "tiny":
        return recorded.name, f"the field's fit, recorded in {recorded.recorded_in}", recorded.name
    return "paper", f"no fit preset recorded in {args.field}: the paper's", None


def _target_envmap(args: argparse.Namespace, scene: "MultiViewScene") -> Any:
    """`--envmap FILE|NAME` or lighting `--target-lighting` of the scene, sanitized by `--sanitize`."""
    from gaffer_envmap import read_envmap
    from gaffer_envmap.errors import NonFiniteError
    from gaffer_nerf.data import load_lighting_envmap

    try:
        if args.envmap is not None:
            if args.target_lighting is not None:
                raise ConfigError(
                    "Pass either `--envmap FILE|NAME` or `--target-lighting K`, not both."
                )
            return read_envmap(_envmap_path(args.envmap), sanitize=args.sanitize)
        if args.target_lighting is not None:
            if not 0 <= args.target_lighting < len(scene.lightings):
                raise ConfigError(
                    f"`--target-lighting` is {args.target_lighting}; {scene.root} has lightings "
                    f"0..{len(scene.lightings) - 1}."
                )
            return load_lighting_envmap(
                scene.lighting(args.target_lighting), args.envmaps, sanitize=args.sanitize
            )
    except NonFiniteError as exc:  # the API's `sanitize=` hint, said as the flag
        raise ConfigError(sanitize_flag_refusal(exc, args.sanitize)) from exc
    raise ConfigError("Pass `--target-lighting K` (with `--envmaps DIR`) or `--envmap FILE`.")


def _envmap_path(text: str) -> Path:
    """A file, else a bundled HDRI name (`gaffer_envmap.bundled_hdris`)."""
    from gaffer_envmap.bundled import bundled_hdris

    path = Path(text).expanduser()
    if path.is_file():
        return path
    bundled = bundled_hdris()
    if text in bundled:
        return bundled[text]
    raise ConfigError(
        f"`--envmap` {text!r} is neither a file nor a bundled HDRI; pass an .exr/.hdr path or one "
        f"of {sorted(bundled)}."
    )


def _check_relight_args(args: argparse.Namespace) -> Any:
    """Every `relight` argument, torch-free: returns the relight config."""
    cfg = _relight_config(args)
    if args.diffusion_preset == "tiny" and args.checkpoint is not None:
        raise ConfigError(
            "`--diffusion-preset tiny` is a random smoke model; drop it or `--checkpoint`."
        )
    if args.base_model is not None and args.checkpoint is None:
        raise ConfigError("`--base-model` goes with the authors' `--checkpoint`; pass both.")
    preflight.check_field_folder(args.field)
    info = preflight.check_data_folder(args.data)
    preflight.check_lighting(info, "--input-lighting", args.input_lighting)
    if args.envmap is not None and args.target_lighting is not None:
        raise ConfigError("Pass either `--envmap FILE|NAME` or `--target-lighting K`, not both.")
    if args.envmap is not None:
        _envmap_path(args.envmap)
    elif args.target_lighting is not None:
        preflight.check_lighting(info, "--target-lighting", args.target_lighting)
    else:
        raise ConfigError("Pass `--target-lighting K` (with `--envmaps DIR`) or `--envmap FILE`.")
    if args.envmaps is not None and not args.envmaps.is_dir():
        raise ConfigError(f"`--envmaps` {args.envmaps} is not a folder; pass the pool's folder.")
    for flag, path, what in (
        ("--checkpoint", args.checkpoint, "a model folder, or leave it out for gaffer-tiny"),
        ("--base-model", args.base_model, "the Zero-1-to-3 XL folder"),
        ("--lpips-backbone", args.lpips_backbone, "torchvision AlexNet weights, or leave it out"),
    ):
        if path is not None:
            preflight.check_existing(path, flag, what)
    preflight.check_output_dir(
        args.out,
        "--out",
        files=(*preflight.FIELD_FILES, "relight_report.json"),
        folders=("relit_views",),
    )
    preflight.check_not_an_input(args.out, "--out", [("field", args.field), ("--data", args.data)])
    preflight.check_device_name(args.device)
    return cfg


def _relight(args: argparse.Namespace) -> int:
    cfg = _check_relight_args(args)
    device = preflight.resolve_device(args.device)

    from gaffer_diffusion import RuntimeConfig
    from gaffer_envmap.atomic import atomic_dir
    from gaffer_nerf.checkpoint import load_field, save_field
    from gaffer_nerf.data import read_gaffer_data_object
    from gaffer_nerf.evaluate import write_images
    from gaffer_nerf.guidance import DiffusionGuide, load_perceptual_loss
    from gaffer_nerf.relight import relight_field, stage2_for_model

    logger.info("loading %s and the field %s", args.data, args.field)
    scene = read_gaffer_data_object(args.data, lighting_index=args.input_lighting)
    env = _target_envmap(args, scene)
    field = load_field(args.field, device=device)
    logger.info("loading the diffusion model (%s)", args.checkpoint or "gaffer-tiny")
    # auto: bf16 weights + channels-last where the CPU has native bf16 and the model is large (the
    # paper's: Stage 1 about 4x faster, `benchmarks/results/cpu_fast.json`); gaffer-tiny stays float32
    dtype = args.dtype or ("float16" if device.startswith("cuda") else "auto")
    loaded = _load_diffusion(args, RuntimeConfig(device=device, dtype=dtype))
    guide = DiffusionGuide(loaded.pipeline, cfg.diffusion)
    s = guide.sampling
    whose = "flags over the model's suggestion" if _sampling_overridden(args) else "the model's own"
    print(  # the one line that says which model and which sampling
        f"relight with {loaded.name}: {s.num_inference_steps} "
        f"{SAMPLER_LABELS[s.scheduler or 'ddim']} "
        f"step{'' if s.num_inference_steps == 1 else 's'}, guidance "
        f"{s.guidance_scale:g}, {s.average_samples} sample(s), mirror average "
        f"{'on' if s.mirror_average else 'off'}, {s.compat!r} encoding"
        f"{', shared noise' if s.shared_noise else ''}, "
        f"{'whole views' if s.crop_fraction is None else f'object-centred crops ({s.crop_fraction:g})'}"
        f" ({whose})"
    )
    choice = loaded.pipeline.dtype_choice
    if choice.dtype != "float32":  # e.g. bf16 on a CPU with AMX (`--dtype auto`, a large model)
        print(choice.note())
    preset, why, fit_preset = _relight_preset_name(args)
    print(f"relight preset {preset} ({why})")
    stage2_off = None
    if args.ablation is None and args.stage2_iterations is None:  # Stage 2 not asked for by name
        cfg, stage2_off = stage2_for_model(cfg, guide.suggested.num_inference_steps)
    if stage2_off is not None:
        print(f"stage 2 off: {stage2_off}")
    perceptual = load_perceptual_loss(args.lpips_backbone, device=device)
    res = relight_field(
        field, scene.train, env, guide, cfg, perceptual, progress=not args.no_progress
    )
    report = json.dumps(
        _jsonable(
            {
                "preset": preset,
                "fit_preset": fit_preset,
                "stage2_off": stage2_off,
                "config": dataclasses.replace(cfg, diffusion=guide.sampling),
                "model": {"name": loaded.name, "source": str(loaded.source)},
                "report": res.report,
            }
        ),
        indent=2,
    )
    # the field, its report and the relit views as one set: built beside --out, renamed in once
    owned = (*preflight.FIELD_FILES, "relight_report.json", "relit_views")
    with atomic_dir(args.out, owned=owned) as stage:
        save_field(res.field, stage, extra={"relight_report.json": report})
        if res.relit_views is not None:
            names = [f"{i:03d}" for i in range(res.relit_views.shape[0])]
            write_images(res.relit_views, stage / "relit_views", names)
    r = res.report
    s1 = cfg.stage1
    targets = (
        ""
        if s1 is None
        else ", stage 1 fits the model's views"
        if s1.target_detail == "model"
        else f", stage 1 fits its change of shading on the input views (radius {s1.transfer_radius_px} px)"
    )
    print(
        f"relight ({args.ablation or ('no-stage2' if stage2_off else 'full')}{targets}): relit views {r.relight_views_seconds:.1f} s, stage 1 "
        f"{r.stage1.seconds if r.stage1 else 0:.1f} s, stage 2 {r.stage2.seconds if r.stage2 else 0:.1f} s, "
        f"total {r.total_seconds:.1f} s -> {args.out}"
    )
    if r.stage2 is not None and r.stage2.skipped_targets:
        print(
            f"stage 2 skipped {r.stage2.skipped_targets} of {r.stage2.iterations} steps whose "
            "guidance target had lost the object (white or black where the render holds it)"
        )
    return 0


def _sampling_overridden(args: argparse.Namespace) -> bool:
    return any(
        v is not None
        for v in (
            args.steps,
            args.scheduler,
            args.guidance,
            args.average_samples,
            args.mirror_average,
            args.compat,
            args.object_fraction,
        )
    )


def _fraction_or_whole(text: str) -> float | str:
    """`--object-fraction`: "whole", or a number (checked by `DiffusionSamplingConfig`)."""
    if text.strip().lower() == "whole":
        return "whole"
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is neither a fraction in (0, 1] (gaffer-tiny: 0.75) nor 'whole'"
        ) from None


def _render(args: argparse.Namespace) -> int:
    preflight.check_field_folder(args.field)
    info = preflight.check_data_folder(args.data)
    preflight.check_split(info, args.split)
    preflight.check_count(args.orbit, "--orbit", high=preflight.MAX_ORBIT_FRAMES)
    if args.orbit is not None:
        preflight.check_fps(args.fps)
    # NNN.png, or frame_NNN.png and orbit.gif
    slots = ("frame_*.png", "orbit.gif") if args.orbit is not None else ("[0-9]*.png",)
    preflight.check_output_dir(args.out, "--out", files=slots)
    preflight.check_device_name(args.device)
    device = preflight.resolve_device(args.device)

    from gaffer_nerf.checkpoint import load_field
    from gaffer_nerf.evaluate import render_views, write_images

    logger.info("loading %s and the field %s", args.data, args.field)
    scene = _scene(args.data, 0 if info.has_lit else None)
    views = _split(scene, args.split)
    field = load_field(args.field, device=device)
    if args.orbit is not None:
        from gaffer_nerf.video import orbit_path, render_orbit

        # orbit the field's (shrunk) box centre: the object, wherever the capture was centred
        center = field.aabb.detach().cpu().double().mean(dim=0)
        cams = orbit_path(views.cameras, args.orbit, center_world=center)
        video = render_orbit(field, cams, args.out, fps=args.fps, progress=not args.no_progress)
        print(f"rendered {len(video.frames)} orbit frames -> {args.out}, {video.gif}")
        return 0
    images = render_views(field, views.cameras)
    names = [f"{i:03d}" for i in range(views.num_views)]
    write_images(images, args.out, names)
    print(f"rendered {len(names)} views -> {args.out}")
    return 0


def _evaluate(args: argparse.Namespace) -> int:
    if args.target_lighting is None and not args.plain:
        raise ConfigError(
            "Pass `--target-lighting K`: scores are against the ground truth under the TARGET "
            "lighting (use `--plain` for a NeRF-Synthetic folder with one lighting)."
        )
    preflight.check_field_folder(args.field)
    info = preflight.check_data_folder(args.data)
    preflight.check_split(info, args.split)
    if not args.plain and args.target_lighting is not None:  # None with --plain (checked above)
        preflight.check_lighting(info, "--target-lighting", args.target_lighting)
    if args.json is not None:
        preflight.check_output_file(args.json, "--json")
    if args.pred_dir is not None:
        preflight.check_output_dir(args.pred_dir, "--pred-dir", files=("[0-9]*.png",))
    if args.lpips_backbone is not None:
        preflight.check_existing(args.lpips_backbone, "--lpips-backbone", "AlexNet weights")
    preflight.check_device_name(args.device)
    device = preflight.resolve_device(args.device)

    from gaffer_diffusion.errors import MetricUnavailableError
    from gaffer_diffusion.metrics import load_perceptual
    from gaffer_nerf.checkpoint import load_field
    from gaffer_nerf.evaluate import evaluate_field, write_images

    logger.info("loading %s and the field %s", args.data, args.field)
    scene = _scene(args.data, None if args.plain else args.target_lighting)
    views = _split(scene, args.split)
    field = load_field(args.field, device=device)
    perceptual: Any = "auto"
    if args.lpips_backbone is not None:
        try:
            perceptual = load_perceptual(args.lpips_backbone)
        except MetricUnavailableError as exc:
            logger.warning("standard LPIPS unavailable (%s); falling back", exc)
    report, pred = evaluate_field(field, views, perceptual=perceptual)
    if args.pred_dir is not None:
        write_images(pred, args.pred_dir, [f"{i:03d}" for i in range(views.num_views)])
    text = report.to_json()
    flicker = None
    if args.flicker:
        from gaffer_nerf.flicker import temporal_flicker

        gt = views.rgb_srgb.permute(0, 3, 1, 2)
        flicker = temporal_flicker(pred, gt, views.alpha)
        payload = json.loads(text)
        payload["flicker"] = dataclasses.asdict(flicker)
        text = json.dumps(payload, indent=2)
    if args.json is not None:
        from gaffer_envmap.atomic import atomic_write

        args.json.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(args.json, lambda tmp: tmp.write_text(text))
    print(report.to_markdown())
    if flicker is not None:
        print(
            f"flicker along the {views.num_views} {args.split} views: {flicker.flicker:.4f} "
            f"(frame-to-frame change vs the ground truth's, object mask; temporal energy "
            f"{flicker.energy_ratio:.2f}x the ground truth's)"
        )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `gaffer-nerf`; returns the exit status."""
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    handlers = {"fit": _fit, "relight": _relight, "render": _render, "evaluate": _evaluate}
    try:
        return handlers[args.command](args)
    except GafferNerfError as exc:  # with --debug (cli_failure) the traceback comes first
        return cli_failure(f"error: {exc.diagnostics()}", 2, args)
    except (ValueError, FileNotFoundError) as exc:
        return cli_failure(f"error: {exc}", 2, args)
    except KeyboardInterrupt:  # Ctrl-C: one line, not a traceback; outputs are written atomically
        return cli_failure(
            "interrupted (Ctrl-C): stopped; files already written are complete", 130, args
        )
    except OSError as exc:  # an unwritable or clashing output path, a full disk
        return cli_failure(f"error: {exc}. Check the path's permissions and free space.", 2, args)


if __name__ == "__main__":
    sys.exit(main())
