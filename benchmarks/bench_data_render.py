"""Cycles render cost vs quality: seconds per image and images/s per core vs resolution and samples,
and noise (PSNR against a high-sample reference) vs samples vs seconds, with and without the OIDN denoiser
and adaptive sampling. Answers: which setting reaches the authors' quality (128 spp + denoiser) fastest?

Scene: pymeshlab's sample cow (real mesh shipped in a package) lit by two bundled CC0 HDRIs, one view,
camera as the paper's renders. Everything is rendered by gaffer-data's own worker processes
(`_render_bench.bench_render` beside this script), so the numbers include Blender's per-image
overhead.

Run: `python benchmarks/bench_data_render.py [--quick] [--update-baseline]`.
"""

import sys
import tempfile
from pathlib import Path

import _common as common
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

NAME = "data_render"


def main(argv: list[str] | None = None) -> int:
    args = common.parse_args(__doc__.splitlines()[0], argv)
    try:
        from _render_bench import RenderBenchConfig, bench_render

        from gaffer_data.recipes import sample_meshes
        from gaffer_data.render.plan import scan_envmaps
    except ImportError as exc:  # pragma: no cover - depends on the installed extras
        common.log(f"skipping {NAME}: gaffer-data[render,filter] is not installed ({exc})")
        return 0
    meshes = sample_meshes()
    cow = meshes.get("cow") or next(iter(meshes.values()))
    if args.quick:
        bench = RenderBenchConfig(
            resolutions=(64,),
            samples=(8, 32),
            denoise=(False, True),
            adaptive_thresholds=(0.01,),
            reference_samples=256,
            lightings=1,
        )
    else:
        bench = RenderBenchConfig(
            resolutions=(128, 256),
            samples=(8, 16, 32, 64, 128),
            denoise=(False, True),
            adaptive_thresholds=(0.0, 0.01),
            reference_samples=1024,
            lightings=2,
        )
    with tempfile.TemporaryDirectory(prefix="gaffer-bench-") as tmp:
        envdir = Path(tmp) / "env"
        envdir.mkdir()
        import gaffer_envmap as ge

        for name in ("sunset", "courtyard"):
            (envdir / f"{name}.exr").symlink_to(ge.bundled_hdri(name))
        result = bench_render([("cow", cow[0])], scan_envmaps(envdir), Path(tmp) / "work", bench)
    meta = common.machine(args.threads)
    target = next((p for p in result.points if p.samples == 128 and p.denoise), None)
    reach = result.fastest_reaching(target.psnr_db, target.resolution) if target else None
    payload = {
        "name": NAME,
        "machine": meta,
        "quick": args.quick,
        "cores": result.cores,
        "images_per_setting": result.images,
        "reference_seconds_per_image": dict(result.reference_seconds_per_image),
        "points": [p.__dict__ for p in result.points],
        "authors_setting_128spp_denoised": target.__dict__ if target else None,
        "fastest_reaching_authors_quality": reach.__dict__ if reach else None,
    }
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for res in sorted({p.resolution for p in result.points}):
        for den in (False, True):
            for thr in sorted({p.adaptive_threshold for p in result.points}):
                pts = sorted(
                    (
                        p
                        for p in result.points
                        if p.resolution == res and p.denoise == den and p.adaptive_threshold == thr
                    ),
                    key=lambda p: p.samples,
                )
                if not pts:
                    continue
                label = f"{res}px {'OIDN' if den else 'raw'} adapt={thr:g}"
                style = "-" if den else "--"
                axes[0].plot(
                    [p.seconds_per_image for p in pts],
                    [p.psnr_db for p in pts],
                    style,
                    marker="o",
                    label=label,
                )
                for p in pts:
                    axes[0].annotate(str(p.samples), (p.seconds_per_image, p.psnr_db), fontsize=7)
                axes[1].plot(
                    [p.samples for p in pts],
                    [p.images_per_second_per_core for p in pts],
                    style,
                    marker="o",
                    label=label,
                )
    axes[0].set_xlabel("seconds per image")
    axes[0].set_ylabel("PSNR vs reference (dB)")
    axes[0].set_xscale("log")
    axes[0].set_title("noise vs time (labels: spp)")
    axes[1].set_xlabel("samples per pixel")
    axes[1].set_ylabel("images / s / core")
    axes[1].set_xscale("log", base=2)
    axes[1].set_yscale("log")
    axes[1].set_title(f"throughput ({common.short_device(meta)})")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    for path in common.write_results(NAME, payload, fig, args.update_baseline):
        common.log(f"wrote {path}")
    for p in result.points:
        print(
            f"{p.resolution:4d}px spp={p.samples:4d} denoise={p.denoise!s:5} adapt={p.adaptive_threshold:<5g} "
            f"{p.seconds_per_image:7.3f} s/img  {p.psnr_db:6.2f} dB"
        )
    if reach:
        print(
            f"fastest reaching 128 spp + OIDN quality ({target.psnr_db:.2f} dB): {reach.samples} spp, "
            f"denoise={reach.denoise}, {reach.seconds_per_image:.3f} s/img vs {target.seconds_per_image:.3f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
