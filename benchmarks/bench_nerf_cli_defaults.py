"""gaffer-nerf's command line with its defaults, as a new user runs it (issue 36 item 1).

Two procedural objects that no test and no earlier choice used (`gaffer-data recipe --procedural 2
--seed 61`) are rendered by `gaffer-data render-multiview` (Blender Cycles, 128 px, 32 samples +
denoiser, 24 train + 6 test views, 2 lightings drawn from the pool {city, courtyard}). Per object:

    gaffer-nerf fit D --out F --preset tiny
    gaffer-nerf relight F --data D --target-lighting 1 --envmaps E --out R      (no --preset)
    gaffer-nerf evaluate F|R --data D --target-lighting 1 --json ...

`relight` without `--preset` takes the preset the field was fitted with (here tiny, read from
F/fit_report.json). With `--paper` the same relight also runs with `--preset paper` (the paper's
2,500 + 500 steps at its learning rates on this small field: the case that whitened the object
before the fix), written to results/nerf_cli_defaults_paper.json. Scores: object (alpha-masked) PSNR of the test views under the target lighting,
relit vs the unrelit field; seconds per command as the commands ran (wall time of the process).

Run: `flock /tmp/gaffer-cpu.lock python benchmarks/bench_nerf_cli_defaults.py --threads 2
[--paper] [--update-baseline]`. The renders are cached under results/runs/nerf_cli_defaults_data/.
"""

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import _common as common

NAME = "nerf_cli_defaults"
OBJECT_SEED = 61
"""Unused anywhere else: the tests use analytic spheres, the benchmarks seeds 7, 21-24, 41-43, 51."""
POOL = ("city", "courtyard")
RESOLUTION, SAMPLES, TRAIN_VIEWS, TEST_VIEWS = 128, 32, 24, 6


def _run(cmd: list[str], env: dict[str, str]) -> tuple[float, str]:
    t0 = time.perf_counter()
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    seconds = time.perf_counter() - t0
    if out.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {out.returncode}: {out.stderr.strip()[-600:]}")
    return seconds, out.stdout


def _renders(root: Path, env: dict[str, str]) -> Path:
    out = root / "renders"
    if (out / "dataset.json").is_file():
        return out
    exe = Path(sys.executable).parent
    recipe = root / "recipe"
    if not (recipe / "objects").is_dir():
        _run([str(exe / "gaffer-data"), "recipe", "--procedural", "2", "--seed", str(OBJECT_SEED), str(recipe)], env)  # fmt: skip
    held = {"objects": root / "held" / "objects", "envmaps": root / "held" / "envmaps"}
    for folder in held.values():
        folder.mkdir(parents=True, exist_ok=True)
    for mesh in sorted((recipe / "objects" / "procedural").iterdir()):
        shutil.copy2(mesh, held["objects"] / mesh.name)
    for name in POOL:
        shutil.copy2(recipe / "envmaps" / f"{name}.exr", held["envmaps"] / f"{name}.exr")
    _run(
        [
            str(exe / "gaffer-data"), "render-multiview", "--objects", str(held["objects"]),
            "--envmaps", str(held["envmaps"]), "--out", str(out), "--lightings", "2",
            "--resolution", str(RESOLUTION), "--samples", str(SAMPLES), "--seed", str(OBJECT_SEED),
            "--workers", "1", "--train-views", str(TRAIN_VIEWS), "--test-views", str(TEST_VIEWS),
            "--no-progress",
        ],
        env,
    )  # fmt: skip
    return out


def _score(
    nerf: str, field: Path, data: Path, json_path: Path, env: dict[str, str]
) -> dict[str, Any]:
    seconds, _ = _run(
        [nerf, "evaluate", str(field), "--data", str(data), "--target-lighting", "1",
         "--json", str(json_path), "--device", "cpu", "--no-progress"],
        env,
    )  # fmt: skip
    rep = json.loads(json_path.read_text())
    return {
        "object_psnr": round(rep["mean_object_raw"]["psnr"], 3),
        "object_aligned_psnr": round(rep["mean_object_aligned"]["psnr"], 3),
        "seconds": round(seconds, 2),
    }


def main() -> None:
    args = common.parse_args(__doc__ or "", [a for a in sys.argv[1:] if a != "--paper"])
    paper = "--paper" in sys.argv[1:]
    threads = args.threads or 2
    env = {**os.environ, "OMP_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads)}
    meta = common.machine(threads)
    name_out = f"{NAME}_paper" if paper else NAME  # the --paper run is its own result file
    root = common.RUNS / f"{NAME}_data"
    t0 = time.perf_counter()
    data_root = _renders(root, env)
    render_s = time.perf_counter() - t0
    nerf = str(Path(sys.executable).parent / "gaffer-nerf")
    envmaps = root / "held" / "envmaps"
    work = root / "work"
    shutil.rmtree(work, ignore_errors=True)
    rows = []
    for obj in sorted(p for p in (data_root / "objects").iterdir() if p.is_dir()):
        w = work / obj.name
        w.mkdir(parents=True)
        common.log(f"  {obj.name}: fit (tiny)")
        fit_s, _ = _run([nerf, "fit", str(obj), "--out", str(w / "field"), "--preset", "tiny", "--device", "cpu", "--no-progress"], env)  # fmt: skip
        row: dict[str, Any] = {"object": obj.name, "fit_seconds": round(fit_s, 2)}
        row["unrelit"] = _score(nerf, w / "field", obj, w / "unrelit.json", env)
        variants = [("default", [])] + ([("paper", ["--preset", "paper"])] if paper else [])
        for name, extra in variants:
            common.log(f"  {obj.name}: relight ({name})")
            relight = [nerf, "relight", str(w / "field"), "--data", str(obj), "--target-lighting", "1",
                       "--envmaps", str(envmaps), "--out", str(w / name), "--device", "cpu",
                       "--no-progress", *extra]  # fmt: skip
            relight_s, stdout = _run(relight, env)
            report = json.loads((w / name / "relight_report.json").read_text())
            s2 = report["report"]["stage2"]
            row[name] = {
                **_score(nerf, w / name, obj, w / f"{name}.json", env),
                "relight_seconds": round(relight_s, 2),
                "preset": report["preset"],
                "preset_line": next(
                    x for x in stdout.splitlines() if x.startswith("relight preset")
                ),
                "stage1_iterations": report["report"]["stage1"]["iterations"],
                "stage2_iterations": s2["iterations"] if s2 else 0,
                "stage2_skipped_targets": s2["skipped_targets"] if s2 else 0,
            }
            row[name]["gain_db"] = round(
                row[name]["object_psnr"] - row["unrelit"]["object_psnr"], 3
            )
            common.log(
                f"    {name}: {row[name]['object_psnr']:.2f} dB vs unrelit {row['unrelit']['object_psnr']:.2f}, {relight_s:.1f} s"
            )
        rows.append(row)
    payload = {
        "name": name_out,
        "description": (__doc__ or "").split("\n\n")[0],
        "model": common.model_provenance(),
        "data": {
            **common.data_provenance(data_root),
            "recipe": f"gaffer-data recipe --procedural 2 --seed {OBJECT_SEED}",
            "render": f"{RESOLUTION} px, {SAMPLES} spp + denoiser, {TRAIN_VIEWS} train + {TEST_VIEWS} test views, pool {list(POOL)}, seed {OBJECT_SEED}",
        },
        "threads": f"OMP_NUM_THREADS={threads} (every command)",
        "render_or_cache_seconds": round(render_s, 2),
        "objects": rows,
        "mean": {
            k: round(sum(r[k]["object_psnr"] for r in rows) / len(rows), 3)
            for k in ("unrelit", "default", *(["paper"] if paper else []))
        },
        "machine": meta,
    }
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3))
    keys = list(payload["mean"])
    for r in rows:
        ax.plot(keys, [r[k]["object_psnr"] for k in keys], "o-", label=r["object"])
    ax.set_ylabel("object PSNR (dB)")
    ax.set_title("gaffer-nerf CLI defaults, 128 px")
    ax.legend()
    for p in common.write_results(name_out, payload, fig, args.update_baseline):
        common.log(f"wrote {p}")
    print(json.dumps(payload["mean"]))


if __name__ == "__main__":
    main()
