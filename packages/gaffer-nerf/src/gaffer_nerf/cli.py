"""Command line: `gaffer-nerf fit | relight | render | evaluate`.

    gaffer-nerf fit DATA --out FIELD [--preset paper|tiny] [--iterations N] [--lighting-index 0]
        [--sizing fixed|footprint] [--early-stopping] [--rank-selection [--rank-ladder 0.25 0.5 1]
        [--rank-tolerance DB]] [--device cuda]
    gaffer-nerf relight FIELD --data DATA --target-lighting K [--envmaps DIR | --envmap FILE]
        (--checkpoint CKPT [--base-model DIR] | --diffusion-preset tiny) --out RELIT
        [--preset paper|tiny] [--ablation full|no-stage1|no-stage2|sds-stage2|sds-only]
        [--t-schedule exponential|authors] [--stage1-iterations N] [--stage2-iterations N]
    gaffer-nerf render FIELD --data DATA [--split test | --orbit N [--fps 12]] --out DIR
    gaffer-nerf evaluate FIELD --data DATA --target-lighting K [--split test] [--json F]

DATA is a gaffer-data multi-view object folder or a NeRF-Synthetic scene (`transforms_*.json`).
FIELD is a folder written by `fit` / `relight` (`config.json` + `field.safetensors`).
`--diffusion-preset tiny` uses a RANDOM tiny model: for smoke tests only, its relighting is noise.
"""

import argparse
import dataclasses
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from gaffer_nerf.checkpoint import load_field, save_field
from gaffer_nerf.configs import (
    ABLATIONS,
    EarlyStoppingConfig,
    RankSelectionConfig,
    fit_preset,
    relight_preset,
)
from gaffer_nerf.data import load_lighting_envmap, read_gaffer_data_object
from gaffer_nerf.data.transforms import MultiViewScene, ViewSet
from gaffer_nerf.errors import ConfigError, GafferNerfError

logger = logging.getLogger(__name__)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="gaffer-nerf", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)

    f = sub.add_parser("fit", help="fit a TensoRF field to the input-lighting views")
    f.add_argument("data", type=Path, help="multi-view folder with transforms_train.json")
    f.add_argument("--out", type=Path, required=True, help="output field folder")
    f.add_argument("--preset", choices=("paper", "tiny"), default="paper")
    f.add_argument("--iterations", type=int, help="override the preset's iteration count")
    f.add_argument("--batch-rays", type=int, help="override the rays per step")
    f.add_argument("--lighting-index", type=int, default=0, help="gaffer-data lighting to fit (0)")
    f.add_argument("--plain", action="store_true", help="NeRF-Synthetic folder: load file_path")
    f.add_argument("--sizing", choices=("fixed", "footprint"), default="fixed")
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
    f.add_argument("--seed", type=int, default=0)

    r = sub.add_parser("relight", help="relight a fitted field under a target lighting")
    r.add_argument("field", type=Path, help="field folder from `fit`")
    r.add_argument("--data", type=Path, required=True, help="the multi-view folder it was fit to")
    r.add_argument("--input-lighting", type=int, default=0, help="lighting of the inputs (0)")
    r.add_argument("--target-lighting", type=int, help="gaffer-data lighting index to relight to")
    r.add_argument("--envmap", type=Path, help="target env map file (instead of --target-lighting)")
    r.add_argument("--envmaps", type=Path, help="folder holding the pool's env maps")
    r.add_argument(
        "--checkpoint", type=Path, help="diffusion model: our folder or checkpoint-80000/"
    )
    r.add_argument("--base-model", type=Path, help="Zero-1-to-3 XL folder (authors' checkpoint)")
    r.add_argument("--diffusion-preset", choices=("tiny",), help="random tiny model (smoke tests)")
    r.add_argument("--out", type=Path, required=True, help="output folder (relit field + report)")
    r.add_argument("--preset", choices=("paper", "tiny"), default="paper")
    r.add_argument("--ablation", choices=ABLATIONS, default="full")
    r.add_argument("--t-schedule", choices=("exponential", "authors"), default="exponential")
    r.add_argument("--stage1-iterations", type=int)
    r.add_argument("--stage2-iterations", type=int)
    r.add_argument("--steps", type=int, help="DDIM steps of the full schedule (50)")
    r.add_argument("--lpips-backbone", type=Path, help="torchvision AlexNet weights (std LPIPS)")

    d = sub.add_parser("render", help="render a field at the poses of a split")
    d.add_argument("field", type=Path)
    d.add_argument("--data", type=Path, required=True)
    d.add_argument("--split", choices=("train", "test"), default="test")
    d.add_argument("--out", type=Path, required=True, help="folder for the PNGs")
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
    e.add_argument("field", type=Path)
    e.add_argument("--data", type=Path, required=True)
    e.add_argument("--target-lighting", type=int, help="lighting of the ground truth")
    e.add_argument("--plain", action="store_true", help="NeRF-Synthetic folder: load file_path")
    e.add_argument("--split", choices=("train", "test"), default="test")
    e.add_argument("--json", type=Path, help="write the report as JSON")
    e.add_argument("--pred-dir", type=Path, help="also write the renders as PNGs here")
    e.add_argument("--lpips-backbone", type=Path, help="torchvision AlexNet weights (std LPIPS)")

    for sp in (f, r, d, e):
        sp.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
        sp.add_argument("--no-progress", action="store_true", help="hide progress bars")
    return p


def _scene(data: Path, lighting: int | None) -> MultiViewScene:
    if lighting is None:
        from gaffer_nerf.data import read_transforms_folder

        return read_transforms_folder(data)
    return read_gaffer_data_object(data, lighting_index=lighting)


def _split(scene: MultiViewScene, split: str) -> ViewSet:
    views = scene.train if split == "train" else scene.test
    if views is None:
        raise ConfigError(f"{scene.root} has no `transforms_{split}.json`; pick --split train.")
    return views


def _jsonable(obj: Any) -> Any:
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
    from gaffer_nerf.fit import fit_tensorf

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
        changes["rank_selection"] = RankSelectionConfig(**sel)
    cfg = dataclasses.replace(cfg, **changes)
    scene = _scene(args.data, None if args.plain else args.lighting_index)
    needs_heldout = args.early_stopping or selecting
    if needs_heldout and scene.test is None:
        raise ConfigError(
            f"`--early-stopping` / `--rank-selection` score held-out views, but {scene.root} has no "
            "`transforms_test.json`; add a test split or drop those flags."
        )
    res = fit_tensorf(
        scene.train,
        cfg,
        heldout=scene.test if needs_heldout else None,
        device=args.device,
        progress=not args.no_progress,
    )
    save_field(res.field, args.out)
    (args.out / "fit_report.json").write_text(json.dumps(_jsonable(res.report), indent=2))
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


def _load_diffusion(args: argparse.Namespace) -> Any:
    from gaffer_diffusion import RelightPipeline, RuntimeConfig

    if args.diffusion_preset == "tiny":
        from gaffer_diffusion.testing import tiny_model

        logger.warning("using a RANDOM tiny diffusion model: the relighting is meaningless")
        model = tiny_model()
    elif args.checkpoint is not None:
        from gaffer_diffusion.loading import MANIFEST_NAME, load_authors_release, load_pretrained

        if (args.checkpoint / MANIFEST_NAME).is_file():
            model = load_pretrained(args.checkpoint).model
        elif args.base_model is None:
            raise ConfigError(
                f"`--checkpoint` {args.checkpoint} is not a gaffer-diffusion folder, so it is taken "
                "as the authors' release, which needs `--base-model DIR` (Zero-1-to-3 XL)."
            )
        else:
            model = load_authors_release(args.checkpoint, args.base_model).model
    else:
        raise ConfigError(
            "Pass `--checkpoint CKPT` (or `--diffusion-preset tiny` for a smoke test)."
        )
    dtype = "float16" if args.device.startswith("cuda") else "float32"
    return RelightPipeline(model, RuntimeConfig(device=args.device, dtype=dtype))


def _relight(args: argparse.Namespace) -> int:
    from gaffer_envmap import read_envmap
    from gaffer_nerf.evaluate import write_images
    from gaffer_nerf.guidance import DiffusionGuide, load_perceptual_loss
    from gaffer_nerf.relight import relight_field

    cfg = relight_preset(args.preset, args.ablation)
    if cfg.stage1 is not None and args.stage1_iterations is not None:
        cfg = dataclasses.replace(
            cfg, stage1=dataclasses.replace(cfg.stage1, iterations=args.stage1_iterations)
        )
    if cfg.stage2 is not None:
        s2 = dataclasses.replace(cfg.stage2, t_schedule=args.t_schedule)
        if args.stage2_iterations is not None:
            s2 = dataclasses.replace(s2, iterations=args.stage2_iterations)
        cfg = dataclasses.replace(cfg, stage2=s2)
    if args.steps is not None:
        cfg = dataclasses.replace(
            cfg, diffusion=dataclasses.replace(cfg.diffusion, num_inference_steps=args.steps)
        )
    scene = read_gaffer_data_object(args.data, lighting_index=args.input_lighting)
    if args.envmap is not None:
        env = read_envmap(args.envmap)
    elif args.target_lighting is not None:
        env = load_lighting_envmap(scene.lighting(args.target_lighting), args.envmaps)
    else:
        raise ConfigError("Pass `--target-lighting K` (with `--envmaps DIR`) or `--envmap FILE`.")
    field = load_field(args.field, device=args.device)
    guide = DiffusionGuide(_load_diffusion(args), cfg.diffusion)
    perceptual = load_perceptual_loss(args.lpips_backbone, device=args.device)
    res = relight_field(
        field, scene.train, env, guide, cfg, perceptual, progress=not args.no_progress
    )
    save_field(res.field, args.out)
    (args.out / "relight_report.json").write_text(
        json.dumps(_jsonable({"config": cfg, "report": res.report}), indent=2)
    )
    if res.relit_views is not None:
        names = [f"{i:03d}" for i in range(res.relit_views.shape[0])]
        write_images(res.relit_views, args.out / "relit_views", names)
    r = res.report
    print(
        f"relight ({args.ablation}): relit views {r.relight_views_seconds:.1f} s, stage 1 "
        f"{r.stage1.seconds if r.stage1 else 0:.1f} s, stage 2 {r.stage2.seconds if r.stage2 else 0:.1f} s, "
        f"total {r.total_seconds:.1f} s -> {args.out}"
    )
    return 0


def _render(args: argparse.Namespace) -> int:
    from gaffer_nerf.evaluate import render_views, write_images

    scene = (
        read_gaffer_data_object(args.data, lighting_index=0)
        if _has_lit(args.data)
        else _scene(args.data, None)
    )
    views = _split(scene, args.split)
    field = load_field(args.field, device=args.device)
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


def _has_lit(data: Path) -> bool:
    path = data / "transforms_train.json"
    if not path.is_file():
        return False
    frames = json.loads(path.read_text()).get("frames") or [{}]
    return bool(frames[0].get("lit"))


def _evaluate(args: argparse.Namespace) -> int:
    from gaffer_diffusion.errors import MetricUnavailableError
    from gaffer_diffusion.metrics import load_perceptual
    from gaffer_nerf.evaluate import evaluate_field, write_images

    if args.target_lighting is None and not args.plain:
        raise ConfigError(
            "Pass `--target-lighting K`: scores are against the ground truth under the TARGET "
            "lighting (use `--plain` for a NeRF-Synthetic folder with one lighting)."
        )
    scene = _scene(args.data, None if args.plain else args.target_lighting)
    views = _split(scene, args.split)
    field = load_field(args.field, device=args.device)
    perceptual: Any = "auto"
    if args.lpips_backbone is not None:
        try:
            perceptual = load_perceptual(args.lpips_backbone)
        except MetricUnavailableError as exc:
            logger.warning("standard LPIPS unavailable (%s); falling back", exc)
    report, pred = evaluate_field(field, views, perceptual=perceptual)
    if args.pred_dir is not None:
        write_images(pred, args.pred_dir, [f"{i:03d}" for i in range(views.num_views)])
    if args.json is not None:
        args.json.write_text(report.to_json())
    print(report.to_markdown())
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of `gaffer-nerf`; returns the exit status."""
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    handlers = {"fit": _fit, "relight": _relight, "render": _render, "evaluate": _evaluate}
    try:
        return handlers[args.command](args)
    except GafferNerfError as exc:
        print(f"error: {exc.diagnostics()}", file=sys.stderr)
        return 2
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # Ctrl-C: one line, not a traceback; outputs are written atomically
        print("interrupted (Ctrl-C): stopped; files already written are complete", file=sys.stderr)
        return 130
    except OSError as exc:  # an unwritable or clashing output path, a full disk
        print(f"error: {exc}. Check the path's permissions and free space.", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
