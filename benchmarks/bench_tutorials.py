"""The tutorials' own runs, measured: what docs/tutorials/insert.md and skies.md show and time.

Every number those two pages state about a run of theirs (how long a command or a figure script takes,
what `gaffer-envmap info` prints, how close the sky is to Blender's) comes from this file's result,
`benchmarks/results/tutorials.json`, which the pages declare (`<!-- numbers-from: ... -->`) and
`docs/_scripts/check_numbers.py` checks them against.

Insert tutorial (`insert`):

- `figure_script`: `python docs/tutorials/insert_figure.py OUT` as a command, wall seconds;
- `shortest_run`: the tutorial's first command (`gaffer-diffusion insert` of the shipped example
  object into the figure's background with `--key-light 120,35`) as a command, wall seconds (Python
  start, imports, model load, insert, write), median of `repeats`;
- `refused_at`: the same command with an `--at` outside the background: exit status 2, wall seconds;
- `sizes`: `insert_object`, the library call the command times and prints, for backgrounds of 512 x 384
  to 4000 x 3000 (a level camera's view of the bundled `courtyard`), the command run in this process
  (`gaffer_diffusion.cli.main`, with this process's `--threads` torch threads) after one warm-up; the seconds of each
  insert and of the model's sampling in it (`relight_under`), median of `repeats`;
- `app`: `Engine.insert` (the app's Insert tab) into a 640 x 480 background, median of `repeats`.

Skies tutorial (`skies`):

- `sun_by_angles`: `gaffer-envmap sky --sun-elevation 35 --sun-azimuth 120` and what
  `gaffer-envmap info` reports for it (`brightest_pixel_direction`), beside the sun's direction;
- `figure`: `docs/tutorials/skies_figure.py` run in this process: per insert, its seconds and the
  shadow's (`--shadow cycles`: Blender's worker, its start included); needs bpy;
- `blender_preetham`: Blender's own PREETHAM sky texture baked (the worker of gaffer-envmap's test
  `test_sun_direction_and_preetham_sky_agree_with_blenders_sky_texture`, same suns) against
  `preetham_sky`: the constant scale between the two (median of Blender / ours over the sky's
  luminance) and how far the ratio strays from one constant (max / min - 1); needs bpy.

    flock /tmp/gaffer-cpu.lock env OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 \
        python benchmarks/bench_tutorials.py --threads 1 --update-baseline

Timings are of the machine it ran on (recorded under `machine`); the pages say which.
"""

import contextlib
import io
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import _common as common
import numpy as np
from PIL import Image

NAME = "tutorials"
REPO = common.REPO
INSERT_FIGURE = REPO / "docs" / "tutorials" / "insert_figure.py"
SKIES_FIGURE = REPO / "docs" / "tutorials" / "skies_figure.py"
SKY_WORKER = REPO / "packages/gaffer-envmap/tests/_blender_scripts/bpy_sky_worker.py"
# (background width, height, object photo side in px or None for the shipped 128 px one, --height)
SIZES: tuple[tuple[int, int, int | None, int | None], ...] = (
    (512, 384, None, None),
    (1024, 768, None, None),
    (1920, 1080, None, None),
    (1920, 1080, 1024, None),
    (4000, 3000, None, 1200),
)
APP_SIZE = (640, 480)
# the suns of gaffer-envmap's Blender agreement test: (elevation, azimuth, turbidity)
PREETHAM_SUNS = ((30.0, 90.0, 3.0), (10.0, 200.0, 5.0))
LUMA = np.array([0.2126, 0.7152, 0.0722])


def _object_path() -> Path:
    from gaffer_diffusion import pretrained

    return pretrained.example_dataset_path() / "objects" / "procedural_002" / "lit" / "000_000.png"


def _env(threads: int) -> dict[str, str]:
    n = str(threads)
    return {**os.environ, "OMP_NUM_THREADS": n, "MKL_NUM_THREADS": n, "PYTHONHASHSEED": "0"}


def _script(name: str) -> str:
    """The venv's console script (as the tutorial types it), else `python -m`."""
    found = Path(sys.executable).parent / name
    return str(found) if found.is_file() else shutil.which(name) or name


def _timed_command(argv: list[str], threads: int, expect: int = 0) -> tuple[float, str]:
    start = time.perf_counter()
    proc = subprocess.run(argv, capture_output=True, text=True, env=_env(threads), check=False)
    seconds = time.perf_counter() - start
    if proc.returncode != expect:
        raise RuntimeError(
            f"{' '.join(argv)} exited {proc.returncode} (expected {expect}):\n"
            + proc.stdout[-2000:]
            + proc.stderr[-2000:]
        )
    # the command's own last line: stdout's (its report), else stderr's (a refusal)
    return seconds, (proc.stdout.strip() or proc.stderr.strip()).splitlines()[-1]


def _background(path: Path, width: int, height: int) -> Path:
    """A level camera's view of the bundled `courtyard` (as the insert figure's background)."""
    from gaffer_diffusion.insert import LEVEL_CAMERA
    from gaffer_diffusion.photo import envmap_backdrop
    from gaffer_envmap.bundled import read_bundled_hdri

    env = read_bundled_hdri("courtyard")
    view = envmap_backdrop(env.radiance_linear, LEVEL_CAMERA.rotation, height=height, width=width)
    Image.fromarray(np.round(np.clip(view, 0.0, 1.0) * 255).astype(np.uint8)).save(path)
    return path


def _enlarged_object(path: Path, side: int) -> Path:
    with Image.open(_object_path()) as im:
        im.convert("RGBA").resize((side, side), Image.Resampling.LANCZOS).save(path)
    return path


@contextlib.contextmanager
def _recording() -> Iterator[list[dict[str, float]]]:
    """Record every `insert_object` call (its seconds, the sampling's and the shadow's) while the
    command or the app runs it: both import it from `gaffer_diffusion.insert` at call time."""
    import gaffer_diffusion.insert as ins

    calls: list[dict[str, float]] = []
    sampling: list[float] = []
    insert_object, relight_under = ins.insert_object, ins.relight_under

    def timed_relight(*args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        out = relight_under(*args, **kwargs)
        sampling.append(time.perf_counter() - start)
        return out

    def timed_insert(*args: Any, **kwargs: Any) -> Any:
        sampling.clear()
        start = time.perf_counter()
        result = insert_object(*args, **kwargs)
        calls.append(
            {
                "insert_s": time.perf_counter() - start,
                "sampling_s": sum(sampling),
                "shadow_s": float(result.shadow_seconds),
            }
        )
        return result

    ins.insert_object, ins.relight_under = timed_insert, timed_relight
    try:
        yield calls
    finally:
        ins.insert_object, ins.relight_under = insert_object, relight_under


def _quiet(fn: Callable[[], int]) -> str:
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert fn() == 0
    return out.getvalue().strip()


def _median(calls: list[dict[str, float]], key: str) -> dict[str, float]:
    return common.Spread.of([c[key] for c in calls]).to_dict()


def insert_sizes(tmp: Path, repeats: int) -> list[dict[str, Any]]:
    from gaffer_diffusion.cli import main

    rows = []
    obj = _object_path()
    for width, height, side, height_px in SIZES:
        background = _background(tmp / f"bg_{width}x{height}.png", width, height)
        photo = _enlarged_object(tmp / f"object_{side}.png", side) if side else obj
        argv = ["insert", str(photo), "--into", str(background), "--out", str(tmp / "out.png")]
        argv += ["--key-light", "120,35"]
        if height_px is not None:
            argv += ["--height", str(height_px)]
        with _recording() as calls:
            line = ""
            for _ in range(repeats + 1):  # the first is a warm-up
                line = _quiet(lambda argv=argv: main(argv))
        kept = calls[1:]
        rows.append(
            {
                "background_wh": [width, height],
                "object_photo_px": side or 128,
                "height_flag": height_px,
                "insert_s": _median(kept, "insert_s"),
                "sampling_s": _median(kept, "sampling_s"),
                "output": line,
            }
        )
        common.log(f"insert {width}x{height} object {side or 128}: {rows[-1]['insert_s']}")
    return rows


def app_insert(tmp: Path, repeats: int) -> dict[str, Any]:
    from gaffer_diffusion.app.config import AppConfig
    from gaffer_diffusion.app.engine import Engine
    from gaffer_diffusion.app.inserting import InsertSettings, key_light_of

    width, height = APP_SIZE
    background = _background(tmp / "bg_app.png", width, height)
    engine = Engine(AppConfig())
    label = engine.model_labels[0]
    settings = InsertSettings(key_light=key_light_of(120.0, 35.0, 3.0, 5.0))
    seconds = []
    for _ in range(repeats + 1):
        outcome = engine.insert(
            label,
            engine.prepare(label, _object_path(), None),
            engine.background(background),
            settings,
        )
        seconds.append(outcome.seconds)
    return {
        "background_wh": [width, height],
        "settings": "key light at azimuth 120, elevation 35, strength 3, 5 degrees; 2d shadow",
        "insert_s": common.Spread.of(seconds[1:]).to_dict(),
    }


def insert_commands(tmp: Path, threads: int, repeats: int) -> dict[str, Any]:
    fig = tmp / "fig"
    figure_s, _ = _timed_command([sys.executable, str(INSERT_FIGURE), str(fig)], threads)
    cmd = [_script("gaffer-diffusion"), "insert", str(_object_path())]
    cmd += ["--into", str(fig / "background.png"), "--out", str(fig / "example.png")]
    runs = [_timed_command([*cmd, "--key-light", "120,35"], threads) for _ in range(repeats)]
    refused = [_timed_command([*cmd, "--at", "5000,10"], threads, expect=2) for _ in range(repeats)]
    return {
        "figure_script": {
            "command": "python docs/tutorials/insert_figure.py fig",
            "wall_s": figure_s,
        },
        "shortest_run": {
            "command": "gaffer-diffusion insert OBJECT --into fig/background.png "
            "--out fig/example.png --key-light 120,35",
            "wall_s": common.Spread.of([s for s, _ in runs]).to_dict(),
            "output": runs[-1][1],
        },
        "refused_at": {
            "command": "the same with --at 5000,10 (outside the 384 x 288 background)",
            "wall_s": common.Spread.of([s for s, _ in refused]).to_dict(),
            "output": refused[-1][1],
        },
    }


def sun_by_angles(tmp: Path) -> dict[str, Any]:
    from gaffer_envmap.cli import main as envmap_main
    from gaffer_envmap.io import read_envmap
    from gaffer_envmap.sky import sun_direction
    from gaffer_envmap.stats import describe

    exr = tmp / "sky.exr"
    flags = ["sky", "--sun-elevation", "35", "--sun-azimuth", "120", "--out", str(exr)]
    _quiet(lambda: envmap_main(flags))
    found = np.array(describe(read_envmap(exr)).brightest_pixel_direction)
    sun = sun_direction(35.0, 120.0)
    angle = float(np.degrees(np.arccos(np.clip(found @ sun, -1.0, 1.0))))
    return {
        "command": "gaffer-envmap sky --sun-elevation 35 --sun-azimuth 120 --out sky.exr; "
        "gaffer-envmap info sky.exr",
        "brightest_pixel_direction": [float(x) for x in found],
        "sun_direction": [float(x) for x in sun],
        "angle_between_deg": angle,
        "pixel_size_deg": 360.0 / 512,
    }


def skies_figure(tmp: Path) -> dict[str, Any]:
    import importlib.util

    spec = importlib.util.spec_from_file_location("skies_figure", SKIES_FIGURE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    start = time.perf_counter()
    with _recording() as calls:
        _quiet(lambda: module.main_figure(tmp / "skies") or 0)
    wall = time.perf_counter() - start
    return {
        "command": "python docs/tutorials/skies_figure.py OUT (in this process)",
        "shadow": module.SHADOW,
        "inserts": [{"sky": name, **c} for name, c in zip(module.SKIES, calls, strict=True)],
        "insert_s": _median(calls, "insert_s"),
        "shadow_s": _median(calls, "shadow_s"),
        "wall_s": wall,
    }


def blender_preetham(tmp: Path, threads: int) -> dict[str, Any]:
    import OpenEXR

    from gaffer_envmap.conventions import direction_grid
    from gaffer_envmap.sky import preetham_sky, sun_direction

    renders = [
        {"sky_type": "PREETHAM", "sun_elevation_deg": el, "sun_rotation_deg": az, "turbidity": t}
        | {"out": str(tmp / f"blender_{k}.exr"), "width": 128, "height": 64}
        for k, (el, az, t) in enumerate(PREETHAM_SUNS)
    ]
    job = tmp / "job.json"
    job.write_text(
        json.dumps({"threads": threads, "result": str(tmp / "result.json"), "renders": renders})
    )
    proc = subprocess.run(
        [sys.executable, str(SKY_WORKER), str(job)],
        capture_output=True,
        text=True,
        env=_env(threads),
        check=False,
    )
    if proc.returncode != 0:
        raise RuntimeError(proc.stdout[-2000:] + proc.stderr[-2000:])
    dirs = direction_grid(64, 128)
    sky = dirs[..., 2] > 0.05
    suns = []
    for (el, az, t), item in zip(PREETHAM_SUNS, renders, strict=True):
        channels = OpenEXR.File(item["out"], separate_channels=True).channels()
        theirs = np.stack([np.asarray(channels[c].pixels, np.float64) for c in "RGB"], -1)[sky]
        ours = preetham_sky(dirs, sun_direction(el, az), t)[sky]
        ratio = (theirs @ LUMA) / (ours @ LUMA)
        chroma = np.abs(theirs / ratio[:, None] - ours) / (ours @ LUMA)[:, None]
        suns.append(
            {
                "sun_elevation_deg": el,
                "sun_azimuth_deg": az,
                "turbidity": t,
                "scale": float(np.median(ratio)),
                "scale_spread": float(ratio.max() / ratio.min() - 1.0),
                "chroma_max": float(chroma.max()),
            }
        )
    return {
        "what": "Blender 5 PREETHAM sky texture baked at 128 x 64 vs preetham_sky, above 0.05 of "
        "the horizon: scale = median of Blender / ours (luminance), spread = max / min - 1",
        "suns": suns,
        "scale_spread_max": max(s["scale_spread"] for s in suns),
    }


def figure(payload: dict[str, Any]) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = payload["insert"]["sizes"]
    labels = [
        f"{r['background_wh'][0]}x{r['background_wh'][1]}"
        + (f"\n{r['object_photo_px']} px photo" if r["object_photo_px"] != 128 else "")
        for r in rows
    ]
    fig, ax = plt.subplots(figsize=(7, 3.6))
    ax.bar(labels, [r["insert_s"]["median"] for r in rows], label="insert")
    ax.bar(labels, [r["sampling_s"]["median"] for r in rows], label="of it: sampling")
    ax.set_ylabel("seconds per insert (median)")
    ax.set_title(common.short_device(payload["machine"]), fontsize=7)
    ax.legend()
    fig.tight_layout()
    return fig


def main(argv: list[str] | None = None) -> int:
    args = common.parse_args(__doc__.splitlines()[0], argv)
    threads = common.set_threads(args.threads)
    meta = common.machine(threads)
    repeats = 1 if args.quick else 3
    import importlib.util

    has_bpy = importlib.util.find_spec("bpy") is not None and not args.quick
    with tempfile.TemporaryDirectory(prefix="bench_tutorials_") as name:
        tmp = Path(name)
        insert: dict[str, Any] = insert_commands(tmp, threads, repeats)
        insert["sizes"] = insert_sizes(tmp, repeats)
        insert["app"] = app_insert(tmp, repeats)
        skies: dict[str, Any] = {"sun_by_angles": sun_by_angles(tmp)}
        skip = "skipped (--quick or no bpy)"
        skies["figure"] = skies_figure(tmp) if has_bpy else skip
        skies["blender_preetham"] = blender_preetham(tmp, threads) if has_bpy else skip
    payload: dict[str, Any] = {
        "name": NAME,
        "description": __doc__,
        "machine": meta,
        "model": common.model_provenance(),
        "settings": {"repeats": repeats, "torch_threads": threads},
        "insert": insert,
        "skies": skies,
    }
    written = common.write_results(NAME, payload, figure(payload), args.update_baseline)
    print(json.dumps({"insert": insert, "skies": skies}, indent=1)[:6000])
    for path in written:
        common.log(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
