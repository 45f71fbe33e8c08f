"""The `gaffer-data` command line: `render`, `render-multiview`, `recipe`, `filter`, `train-classifier`,
`convert-authors`, `schema`, `info`.

Exit codes: 0 done; 1 some objects failed (`render`, `render-multiview`, `convert-authors`: the
others were written, rerun to retry) or `info --verify` found incomplete objects; 2 refused or
failed (one stderr line naming the argument and the fix); 130 interrupted (Ctrl-C; finished objects
are kept). `--debug` also prints the traceback of an expected failure."""

import argparse
import dataclasses
import json
import logging
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from gaffer_data.errors import GafferDataError
from gaffer_envmap.cli_support import (
    add_debug_argument,
    check_output_dir,
    check_output_file,
    cli_failure,
    exit_codes_epilog,
    output_path,
)
from gaffer_envmap.errors import GafferEnvmapError
from gaffer_envmap.sanitize import add_sanitize_argument

if TYPE_CHECKING:
    from gaffer_data.config import RenderConfig


EXIT_CODES = {
    0: "done",
    1: "some objects failed (render, render-multiview, convert-authors; the others were written, "
    "rerun to retry) or `info --verify` found incomplete objects",
    2: "refused or failed (one stderr line naming the argument and the fix)",
    130: "interrupted (Ctrl-C; finished objects are kept, rerun to resume)",
}
"""What `main` returns (documented in `--help` and docs/cli.md)."""


def _common_config(args: argparse.Namespace) -> dict[str, object]:
    from gaffer_data.config import AugmentConfig

    return {
        "lightings": args.lightings,
        "resolution": args.resolution,
        "samples": args.samples,
        "seed": args.seed,
        "denoise": not args.no_denoise,
        "adaptive_threshold": args.adaptive_threshold,
        "view_transform": args.view_transform,
        "background_visible": args.background_visible,
        "world_map_resolution": args.world_map_resolution,
        "envmap_sanitize": args.sanitize,
        "augment": AugmentConfig(flip=not args.no_flip, yaw_steps=args.yaw_steps),
    }


MAX_RESOLUTION = 8192
"""Largest `--resolution`: one 8192^2 RGBA float32 film is 1 GiB in Cycles, several are held at once."""
MAX_SAMPLES = 1 << 16
MAX_PROCEDURAL = 10_000
"""Largest `recipe --procedural`: about 40 s of Blender per 100 objects, so a few hours at most."""

PYBULLET_RANDOM_MESHES = 1000
"""pybullet_data ships random_urdfs 000-999 (`recipe --pybullet`)."""


def _check_render_args(args: argparse.Namespace) -> None:
    """Cheap checks before any scan or Blender start: one line naming the flag and the fix."""
    from gaffer_data.errors import ConfigError

    if args.timeout is not None and not args.timeout > 0:
        raise ConfigError(
            f"`--timeout` is {args.timeout}; pass seconds > 0, or leave it out for no limit."
        )
    if not 8 <= args.resolution <= MAX_RESOLUTION:
        raise ConfigError(
            f"`--resolution` is {args.resolution}; pass 8..{MAX_RESOLUTION} px (one "
            f"{args.resolution}^2 float film would need "
            f"{args.resolution**2 * 16 / 2**30:.1f} GiB)."
        )
    if not 1 <= args.samples <= MAX_SAMPLES:
        raise ConfigError(f"`--samples` is {args.samples}; pass 1..{MAX_SAMPLES} per pixel.")
    if args.workers < 1:
        raise ConfigError(f"`--workers` is {args.workers}; pass 1 or more.")
    if args.retries < 0:
        raise ConfigError(f"`--retries` is {args.retries}; pass 0 or more.")
    if args.lightings < 0:
        raise ConfigError(f"`--lightings` is {args.lightings}; pass 0 or more.")
    if args.yaw_steps < 1:
        raise ConfigError(f"`--yaw-steps` is {args.yaw_steps}; pass 1 (no yaw) or more.")
    if not 0 <= args.world_map_resolution <= 16384:
        raise ConfigError(
            f"`--world-map-resolution` is {args.world_map_resolution}; pass 0 (automatic)..16384."
        )
    _check_seed(args.seed)
    # the dataset folder: its manifests are files, objects/ a folder (checked before any scan)
    check_output_dir(
        "--out",
        args.out,
        files=("dataset.json", "failures.jsonl"),
        folders=("objects",),
    )


MAX_SEED = 2**63 - 1
"""Largest `--seed` (numpy's seed sequences take any non-negative integer; this keeps it an int64)."""


def _check_seed(seed: int) -> None:
    from gaffer_data.errors import ConfigError

    if not 0 <= seed <= MAX_SEED:
        raise ConfigError(f"`--seed` is {seed}; pass an integer in 0..{MAX_SEED} (e.g. 0).")


def _run_render(args: argparse.Namespace, config: "RenderConfig") -> int:
    from gaffer_data.recipes import scan_objects
    from gaffer_data.render.plan import scan_envmaps
    from gaffer_data.render.runner import Dispatch, RunOptions, Shard, render_dataset

    options = RunOptions(
        workers=args.workers,
        retries=args.retries,
        timeout_s=args.timeout,
        shard=Shard.parse(args.shard),
        progress=not args.no_progress,
    )
    dispatch: Dispatch | None = None
    if args.backend == "ray":
        from gaffer_data.render.ray_backend import RayDispatch, RayOptions

        # Fails fast, before scanning, when ray is missing.
        dispatch = RayDispatch(
            RayOptions(address=args.ray_address, cpus_per_task=args.cpus_per_task)
        )
    elif args.ray_address is not None or args.cpus_per_task is not None:
        raise GafferDataError(
            "`--ray-address` and `--cpus-per-task` only apply to `--backend ray`; "
            f"got `--backend`={args.backend!r}."
        )
    objects = scan_objects(args.objects)
    pool = scan_envmaps(args.envmaps) if config.lightings > 0 else ()
    summary = render_dataset(objects, pool, args.out, config, options, dispatch=dispatch)
    per_image = sum(summary.image_seconds) / max(1, summary.images)
    print(
        f"rendered {len(summary.rendered)} objects ({summary.images} images, {per_image:.2f} s/image), "
        f"skipped {len(summary.skipped)} complete, failed {len(summary.failed)} in {summary.seconds:.1f} s"
    )
    for failure in summary.failed:
        print(f"  failed {failure.object_id}: {failure.reason}", file=sys.stderr)
    return 0 if not summary.failed else 1


def _render(args: argparse.Namespace) -> int:
    from gaffer_data.config import RenderConfig

    _check_render_args(args)
    config = RenderConfig(
        views=args.views,
        area_light_render=not args.no_area_light,
        **_common_config(args),  # type: ignore[arg-type]
    )
    return _run_render(args, config)


def _render_multiview(args: argparse.Namespace) -> int:
    from gaffer_data.config import MultiviewConfig, multiview_render_config

    _check_render_args(args)
    multiview = MultiviewConfig(
        train_views=args.train_views,
        test_views=args.test_views,
        layout=args.layout,
        elevation_deg=(args.min_elevation, args.max_elevation),
        orbit_elevation_deg=args.orbit_elevation,
        distance=args.distance,
    )
    config = multiview_render_config(
        multiview, area_light_render=args.area_light, **_common_config(args)
    )
    return _run_render(args, config)


def _recipe(args: argparse.Namespace) -> int:
    from gaffer_data.errors import ConfigError
    from gaffer_data.recipes import build_default_recipe

    if not 0 <= args.procedural <= MAX_PROCEDURAL:
        raise ConfigError(
            f"`--procedural` is {args.procedural}; expected a count in 0..{MAX_PROCEDURAL}."
        )
    if not 0 <= args.pybullet <= PYBULLET_RANDOM_MESHES:
        raise ConfigError(
            f"`--pybullet` is {args.pybullet}; expected a count in 0..{PYBULLET_RANDOM_MESHES}."
        )
    if not 0 <= args.pybullet_first <= PYBULLET_RANDOM_MESHES - args.pybullet:
        raise ConfigError(
            f"`--pybullet-first` is {args.pybullet_first}; expected 0..{PYBULLET_RANDOM_MESHES} minus"
            " `--pybullet` (pybullet_data ships random_urdfs 000-999)."
        )
    if not args.out.strip():  # Path("") would be the current folder
        raise ConfigError("`out` is empty; pass the folder to write the recipe into.")
    _check_seed(args.seed)
    check_output_dir(
        "out",
        args.out,
        files=("envmaps/*.exr",),
        folders=("objects", "envmaps", "objects/procedural", "objects/pybullet"),
    )
    recipe = build_default_recipe(
        Path(args.out),
        procedural=args.procedural,
        seed=args.seed,
        pybullet=args.pybullet,
        pybullet_first=args.pybullet_first,
    )
    print(f"objects: {recipe.objects}\nenvmaps: {recipe.envmaps}")
    return 0


def _filter(args: argparse.Namespace) -> int:
    from gaffer_data.filter.run import filter_objects

    check_output_file("--out", args.out)
    summary = filter_objects(
        args.src,
        args.out,
        rules_path=args.rules,
        classifier_path=args.classifier,
        workers=args.workers,
        timeout_s=args.timeout if args.timeout != 0 else None,
        annotations_path=args.annotations,
        max_worker_memory_mb=args.max_worker_memory_mb,
    )
    print(f"accepted {summary.accepted} / {summary.total} objects -> {args.out}")
    return 0


def _train(args: argparse.Namespace) -> int:
    from gaffer_data.filter.classifier import train_classifier

    check_output_dir("--out", args.out, files=("model.pkl", "classifier.json"))
    report = train_classifier(args.features, args.labels, args.out, folds=args.folds)
    print(json.dumps(dataclasses.asdict(report), indent=1))
    return 0


def _convert_authors(args: argparse.Namespace) -> int:
    from gaffer_data.convert import ConvertOptions, convert_authors
    from gaffer_data.dataset.manifest import read_json_value

    check_output_dir("--out", args.out, files=("dataset.json",), folders=("objects",))
    object_ids = None
    if args.object_list is not None:
        ids = read_json_value(args.object_list)
        if not isinstance(ids, list) or not all(isinstance(i, str) for i in ids):
            raise GafferDataError(
                f"`--object-list`={str(args.object_list)!r} must be a JSON list of object ids, "
                "like the authors' val_unseen_object_list.json."
            )
        object_ids = tuple(ids)
    options = ConvertOptions(lighting=args.lighting, object_ids=object_ids, hardlink=args.hardlink)
    summary = convert_authors(args.src, args.out, options)
    print(
        f"converted {len(summary.converted)} objects ({summary.images} images), "
        f"skipped {len(summary.skipped_complete)} already converted, failed {len(summary.failed)}"
    )
    for failure in summary.failed:
        print(f"  failed {failure.object_id}: {failure.reason}", file=sys.stderr)
    return 0 if not summary.failed else 1


def _schema(args: argparse.Namespace) -> int:
    from gaffer_data.dataset.json_schema import write_schemas

    check_output_dir("--out", args.out, files=("*.schema.json",))
    for path in write_schemas(args.out):
        print(path)
    return 0


def _info(args: argparse.Namespace) -> int:
    from gaffer_data.dataset import open_dataset
    from gaffer_data.errors import InputError

    root = Path(args.root)
    if root.is_dir() and not (root / "dataset.json").is_file() and not (root / "objects").is_dir():
        raise InputError(
            f"`root`={str(root)!r} is not a gaffer-data dataset (no dataset.json, no objects/); "
            "pass the `--out` folder of `gaffer-data render`."
        )
    ds = open_dataset(root)
    images = 0
    for obj in ds.iter_objects(verify=args.verify):
        images += sum(len(v.lit) + (v.area is not None) for v in obj.views)
    print(f"{len(ds)} complete objects, {images} images, {len(ds.failures)} failed")
    for failure in ds.failures:
        print(f"  failed {failure.object_id}: {failure.reason}")
    # object folders without a manifest: still rendering, killed, or a deleted manifest.json
    listed = set(ds.object_ids)
    unlisted = sorted(
        p.name
        for p in (root / "objects").glob("*")
        if p.is_dir() and not p.name.startswith(".") and p.name not in listed
    )
    if unlisted:
        shown = ", ".join(unlisted[:5]) + (", ..." if len(unlisted) > 5 else "")
        print(f"  {len(unlisted)} object folder(s) without manifest.json (incomplete): {shown}")
    if args.verify and unlisted:
        print(
            "error: --verify: some object folders have no manifest.json; rerun the render into "
            "this folder to finish them",
            file=sys.stderr,
        )
        return 1
    return 0


def _add_render_args(r: argparse.ArgumentParser, *, lightings: int) -> None:
    r.add_argument("--objects", required=True, type=Path, help="mesh folder or filter .jsonl")
    r.add_argument("--envmaps", required=True, type=Path, help="folder of .exr/.hdr lat-long maps")
    add_sanitize_argument(
        r, what="checked for every --envmaps map before any render; the renders use its pixels: "
    )
    r.add_argument(
        "--out",
        required=True,
        type=output_path,
        help="dataset folder (created; rerun into it to resume, same options only)",
    )
    r.add_argument(
        "--lightings",
        type=int,
        default=lightings,
        help="environment-map renders per view (default: %(default)s)",
    )
    r.add_argument(
        "--resolution", type=int, default=512, help="square image side in pixels (default: 512)"
    )
    r.add_argument(
        "--samples", type=int, default=128, help="Cycles samples per pixel (default: 128)"
    )
    r.add_argument(
        "--seed",
        type=int,
        default=0,
        help="root seed: each object's cameras and envmap draws come from (seed, object id) only",
    )
    r.add_argument(
        "--workers", type=int, default=1, help="objects rendered at once, one Blender worker each"
    )
    r.add_argument("--shard", default="0/1", help="i/N: render the i-th of N shards")
    r.add_argument(
        "--backend",
        choices=["local", "ray"],
        default="local",
        help="local: worker subprocesses here; ray: one Ray task per object (gaffer-data[ray])",
    )
    r.add_argument(
        "--ray-address",
        default=None,
        help="Ray cluster to join (default: $RAY_ADDRESS, else a local instance of --workers tasks)",
    )
    r.add_argument(
        "--cpus-per-task",
        type=int,
        default=None,
        help="Ray CPUs and Cycles threads per object task (default: cpu_count // workers)",
    )
    r.add_argument(
        "--retries",
        type=int,
        default=1,
        help="extra attempts for a failing object before it is recorded as failed (default: 1)",
    )
    r.add_argument("--timeout", type=float, default=None, help="seconds per worker attempt")
    r.add_argument(
        "--no-denoise", action="store_true", help="skip the OpenImageDenoise pass (default: on)"
    )
    r.add_argument(
        "--adaptive-threshold",
        type=float,
        default=0.01,
        help="Cycles adaptive-sampling noise threshold (0: off; default: 0.01, Blender's)",
    )
    r.add_argument(
        "--view-transform",
        default="Filmic",
        help="Blender view transform of the PNGs: Filmic (default, the paper's), AgX, Standard, "
        "'Khronos PBR Neutral' or Raw; the EXRs stay linear",
    )
    r.add_argument(
        "--background-visible",
        action="store_true",
        help="show the environment map behind the object (default: transparent film, alpha = mask)",
    )
    r.add_argument("--world-map-resolution", type=int, default=0, help="0: Blender's automatic")
    r.add_argument(
        "--no-flip", action="store_true", help="never mirror an envmap draw (default: half are)"
    )
    r.add_argument(
        "--yaw-steps",
        type=int,
        default=8,
        help="envmap draws are yawed by k/N of a turn, k uniform below N (default: 8; 1: no yaw)",
    )
    r.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `gaffer-data` (exposed for docs and tests)."""
    from gaffer_data.filter.memory_cap import DEFAULT_MAX_WORKER_MEMORY_MB

    parser = argparse.ArgumentParser(
        prog="gaffer-data",
        description=(__doc__ or "").split("\n\n")[0],
        epilog=exit_codes_epilog(EXIT_CODES),
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log INFO messages to stderr")
    sub = parser.add_subparsers(dest="command", required=True)

    r = sub.add_parser("render", help="render objects under environment maps with Blender Cycles")
    _add_render_args(r, lightings=16)
    r.add_argument("--views", type=int, default=12, help="camera views per object (default: 12)")
    r.add_argument(
        "--no-area-light",
        action="store_true",
        help="skip the area-light render and its normal/albedo/depth passes (default: rendered)",
    )
    r.set_defaults(func=_render)

    m = sub.add_parser(
        "render-multiview",
        help="render multi-view 3D sets (train/test splits, shared lightings, transforms_*.json)",
    )
    _add_render_args(m, lightings=4)
    m.add_argument(
        "--train-views", type=int, default=100, help="views of the train split (default: 100)"
    )
    m.add_argument(
        "--test-views", type=int, default=20, help="held-out views of the test split (default: 20)"
    )
    m.add_argument(
        "--layout",
        choices=["sphere", "orbit"],
        default="sphere",
        help="sphere: a Fibonacci lattice over the elevation band (default); orbit: one ring",
    )
    m.add_argument("--min-elevation", type=float, default=-30.0, help="sphere layout, degrees")
    m.add_argument("--max-elevation", type=float, default=90.0, help="sphere layout, degrees")
    m.add_argument("--orbit-elevation", type=float, default=30.0, help="orbit layout, degrees")
    m.add_argument("--distance", type=float, default=2.0, help="camera distance to the origin")
    m.add_argument("--area-light", action="store_true", help="also render area light + passes")
    m.set_defaults(func=_render_multiview)

    c = sub.add_parser("recipe", help="write the embedded default recipe (no downloads)")
    c.add_argument("out", help="folder the recipe's objects/ and envmaps/ go into")
    c.add_argument("--procedural", type=int, default=8, help="procedural objects to add (>= 0)")
    c.add_argument("--seed", type=int, default=0, help="seed of the procedural objects")
    c.add_argument(
        "--pybullet",
        type=int,
        default=0,
        help="pybullet_data random_urdfs meshes to add with random materials (needs pybullet)",
    )
    c.add_argument(
        "--pybullet-first",
        type=int,
        default=0,
        help="first random_urdfs index (disjoint ranges give disjoint splits)",
    )
    c.set_defaults(func=_recipe)

    f = sub.add_parser("filter", help="compute features, apply rules and a classifier")
    f.add_argument(
        "src", type=Path, help="mesh folder, or an Objaverse cache (glbs/<group>/<uid>.glb)"
    )
    f.add_argument("--out", required=True, type=output_path, help="output .jsonl manifest")
    f.add_argument("--rules", type=Path, default=None, help="rules JSON (see FilterRules)")
    f.add_argument("--classifier", type=Path, default=None, help="trained classifier folder")
    f.add_argument("--workers", type=int, default=1, help="feature-extraction processes")
    f.add_argument(
        "--timeout",
        type=float,
        default=300.0,
        help="seconds per object before it is rejected as 'timeout after N s' (0: no limit)",
    )
    f.add_argument(
        "--annotations",
        type=Path,
        default=None,
        help="Objaverse annotation JSON[.gz] (uid -> annotation; default: the cache's own "
        "annotations.json[.gz] or metadata/*.json.gz)",
    )
    f.add_argument(
        "--max-worker-memory-mb",
        type=int,
        default=DEFAULT_MAX_WORKER_MEMORY_MB,
        help="MiB of memory one object may add to its worker before it is rejected as 'worker "
        f"exceeded memory cap of N MB' (Linux RLIMIT_AS; default {DEFAULT_MAX_WORKER_MEMORY_MB}; "
        "0: no cap)",
    )
    f.set_defaults(func=_filter)

    t = sub.add_parser(
        "train-classifier", help="train the quality classifier from labelled objects"
    )
    t.add_argument("features", type=Path, help="a `filter` .jsonl manifest (features)")
    t.add_argument("labels", type=Path, help="CSV with columns object_id,label (1 good, 0 bad)")
    t.add_argument(
        "--out", required=True, type=output_path, help="folder for the trained classifier (created)"
    )
    t.add_argument(
        "--folds", type=int, default=5, help="stratified cross-validation folds (default: 5)"
    )
    t.set_defaults(func=_train)

    a = sub.add_parser(
        "convert-authors", help="convert the authors' released layout into a gaffer artifact"
    )
    a.add_argument("src", type=Path, help="a split folder: <split>/<obj>/{VVV}_{LLL}_{env}.png ...")
    a.add_argument(
        "--out", required=True, type=output_path, help="artifact folder (created; rerun to resume)"
    )
    a.add_argument(
        "--lighting",
        type=Path,
        default=None,
        help="folder with LDR/ and HDR_rescaled/ (or HDR_normalized/) per object (default: SRC)",
    )
    a.add_argument("--object-list", type=Path, default=None, help="JSON list of object ids")
    a.add_argument("--hardlink", action="store_true", help="hard-link instead of copying")
    a.set_defaults(func=_convert_authors)

    s = sub.add_parser(
        "schema",
        help="write JSON Schemas (draft 2020-12) of the rendered and the converted (convert-authors) "
        "manifest.json and dataset.json",
    )
    s.add_argument(
        "--out", required=True, type=output_path, help="folder for the *.schema.json files"
    )
    s.set_defaults(func=_schema)

    i = sub.add_parser("info", help="summarise (and optionally verify) a rendered dataset")
    i.add_argument("root", type=Path, help="a dataset folder written by `gaffer-data render`")
    i.add_argument("--verify", action="store_true", help="check every file's sha256")
    i.set_defaults(func=_info)
    add_debug_argument(parser)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `gaffer-data` console script."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        return int(args.func(args))
    except GafferDataError as exc:  # with --debug (cli_failure) the traceback comes first
        return cli_failure(f"error: {exc.diagnostics()}", 2, args)
    except GafferEnvmapError as exc:  # env-map I/O of a sibling package: one line too
        return cli_failure(f"error: {exc}", 2, args)
    except KeyboardInterrupt:  # Ctrl-C: one line, not a traceback; outputs are written atomically
        return cli_failure(
            "interrupted (Ctrl-C): stopped; finished objects are kept, rerun to resume", 130, args
        )
    except OSError as exc:  # an unwritable or clashing output path, a full disk
        return cli_failure(f"error: {exc}. Check the path's permissions and free space.", 2, args)


if __name__ == "__main__":
    sys.exit(main())
