"""Generate everything under docs/_generated/ from code: figures, tables, API pages, tutorial outputs.

Called by docs/conf.py at `builder-inited`; also runnable alone:
`python docs/_scripts/make_figures.py [--out docs/_generated]`.

- `conventions_table.md`: the lat-long conventions table, computed from `gaffer_envmap.conventions`
  (directions at u = 0, 0.25, 0.5, 0.75 and the top row come from `uv_to_direction`, not from prose).
- `conventions.png`: a bundled HDRI in the Blender world layout, and the same light rotated into a camera
  (layout "neural-gaffer-camera"), with labelled directions and the sun marked where the math says it is.
- `camera_poses.png`: one camera drawn with Blender w2c axes and with OpenCV c2w axes.
- `encodings.png`, `normaliser.png`: the same map and pose encoded both ways, their difference; the HDR
  normaliser of each mode as the camera turns.
- `tutorial/`: outputs and figures of `tutorial.py`, executed section by section.
- `bench_*.md` + `bench/*.png`: the committed benchmark baselines (benchmarks/results/).
- (a check, no output) every `gaffer-*` command in the pages' shell blocks parses (`check_commands.py`).
- `api/<package>.md`: each package's re-exports; `api/<package>/<module>.md`: one autodoc page per public
  module (subpackages included) of the four packages.
"""

import argparse
import contextlib
import importlib
import io
import json
import pkgutil
import shutil
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import torch

import gaffer_envmap as ge
from gaffer_envmap.io import read_envmap
from gaffer_envmap.preview import tonemap_preview

DOCS = Path(__file__).resolve().parent.parent
REPO = DOCS.parent
BENCH = REPO / "benchmarks" / "results"
SCRIPTS = Path(__file__).resolve().parent

# One pose used by several figures: a camera 30 degrees round from +x, 15 degrees up, looking at the origin.
FIG_AZIMUTH, FIG_ELEVATION = 30.0, 15.0


# --------------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------------
def _write(path: Path, text: str) -> None:
    """Write only when the content changes (keeps Sphinx's incremental rebuilds incremental)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.exists() or path.read_text() != text:
        path.write_text(text)


def _save(fig: plt.Figure, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight", metadata={"Software": None})
    plt.close(fig)


def _axis_label(vec: np.ndarray, names: tuple[str, str, str] = ("X", "Y", "Z")) -> str:
    """ "+X" for a unit axis, else the rounded vector."""
    v = np.asarray(vec, float)
    k = int(np.argmax(np.abs(v)))
    if abs(abs(v[k]) - 1) < 1e-9:
        return f"{'+' if v[k] > 0 else '−'}{names[k]}"
    return "(" + ", ".join(f"{x:+.2f}" for x in v) + ")"


CAMERA_NAMES = {
    "+x": "+x right",
    "−x": "−x left",
    "+y": "+y up",
    "−y": "−y down",
    "−z": "−z forward (view)",
    "+z": "+z toward viewer",
}


def _dir_label(conv: str, u: float, v: float) -> str:
    d = ge.uv_to_direction(np.array(u), np.array(v), conv)
    if ge.get_convention(conv).frame == "camera":
        return CAMERA_NAMES.get(_axis_label(d, ("x", "y", "z")), _axis_label(d, ("x", "y", "z")))
    return _axis_label(d)


def load_sunset() -> ge.EnvironmentMap:
    """The bundled "sunset" HDRI (lossy EXR with a few negative pixels, hence sanitize="zero")."""
    return read_envmap(ge.bundled_hdri("sunset"), sanitize="zero")


# --------------------------------------------------------------------------------------------------
# Conventions
# --------------------------------------------------------------------------------------------------
def conventions_table() -> str:
    """Markdown table of every registered convention (aliases grouped)."""
    groups: dict[int, list[str]] = {}
    for name, conv in ge.CONVENTIONS.items():
        groups.setdefault(id(conv), []).append(name)
    lines = [
        "| convention | frame | up (top row) | u = 0 / 1 (seam) | u = 0.25 | u = 0.5 (centre) | u = 0.75 "
        "| chirality | file alignment | to Blender world | source |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for names in groups.values():
        conv = ge.get_convention(names[0])
        axis = ("x", "y", "z") if conv.frame == "camera" else ("X", "Y", "Z")
        cells = [
            _axis_label(ge.uv_to_direction(np.array(u), np.array(0.5), names[0]), axis)
            for u in (0.0, 0.25, 0.5, 0.75)
        ]
        top = _axis_label(ge.uv_to_direction(np.array(0.5), np.array(0.0), names[0]), axis)
        m = np.asarray(conv.to_blender)
        mat = (
            "I"
            if np.allclose(m, np.eye(3))
            else "(x, y, z) → ("
            + ", ".join(
                "".join(f"{'+' if c > 0 else '−'}{'xyz'[j]}" for j, c in enumerate(row) if c != 0)
                for row in m
            )
            + ")"
        )
        title = " = ".join(f"`{n}`" for n in names)
        source = conv.source.replace("|", "\\|")
        lines.append(
            f"| {title} | {conv.frame} | {top} | {cells[0]} | {cells[1]} | {cells[2]} | {cells[3]} "
            f"| {ge.chirality(names[0]):+d} | {conv.file_alignment} | {mat} | {source} |"
        )
    return "\n".join(lines) + "\n"


def _label_latlong(ax: plt.Axes, conv: str, width: int, height: int) -> None:
    for u in (0.0, 0.25, 0.5, 0.75, 1.0):
        ax.axvline(u * width - 0.5, color="white", lw=0.8, ls=":" if u % 0.5 else "-", alpha=0.8)
    ax.axhline(height / 2 - 0.5, color="white", lw=0.8, ls=":", alpha=0.8)
    ticks = [0.0, 0.25, 0.5, 0.75, 1.0]
    ax.set_xticks([u * width - 0.5 for u in ticks])
    ax.set_xticklabels([f"u={u:g}\n{_dir_label(conv, u % 1.0, 0.5)}" for u in ticks], fontsize=8)
    ax.set_yticks([-0.5, height / 2 - 0.5, height - 0.5])
    ax.set_yticklabels(
        [
            f"v=0  {_dir_label(conv, 0.5, 0.0)}",
            "v=0.5 horizon",
            f"v=1  {_dir_label(conv, 0.5, 1.0)}",
        ],
        fontsize=8,
    )


def conventions_figure(env: ge.EnvironmentMap, path: Path) -> dict[str, object]:
    """Blender world layout vs neural-gaffer-camera layout, with the sun placed by the math."""
    pose = ge.orbit_w2c_blender(FIG_AZIMUTH, FIG_ELEVATION, 2.0)
    world = env.radiance_linear
    cam = ge.rotate_to_camera(env, pose, height=env.height)[0, 0].numpy()  # [He, 2He, 3]
    # Sun: brightest pixel of the world map -> direction -> R d -> (u, v) in the camera layout.
    lum = world @ np.array([0.2126, 0.7152, 0.0722])
    i, j = np.unravel_index(int(np.argmax(lum)), lum.shape)
    d_world = ge.direction_grid(env.height, env.width)[i, j]
    d_cam = pose.rotation @ d_world
    u_w, v_w = ge.direction_to_uv(d_world, "blender")
    u_c, v_c = ge.direction_to_uv(d_cam, "neural-gaffer-camera")

    fig, axes = plt.subplots(2, 1, figsize=(9.5, 10.0))
    for ax, img, conv, (u, v), title in (
        (
            axes[0],
            world,
            "blender",
            (u_w, v_w),
            'convention "blender" (world, z up): u = 0.5 − atan2(y, x) / 2π, v = acos(z) / π',
        ),
        (
            axes[1],
            cam,
            "neural-gaffer-camera",
            (u_c, v_c),
            f'layout "neural-gaffer-camera": the same light seen by a camera at azimuth {FIG_AZIMUTH:g}°, '
            f"elevation {FIG_ELEVATION:g}°\n(Blender camera axes: x right, y up, the camera looks along −z)",
        ),
    ):
        h, w = img.shape[:2]
        ax.imshow(tonemap_preview(img), interpolation="bilinear")
        _label_latlong(ax, conv, w, h)
        ax.plot(
            float(u) * w - 0.5,
            float(v) * h - 0.5,
            marker="o",
            ms=16,
            mfc="none",
            mec="yellow",
            mew=2,
        )
        ax.annotate(
            "sun (brightest pixel,\nplaced by direction_to_uv)",
            (float(u) * w, float(v) * h),
            xytext=(12 if u < 0.75 else -130, -30),
            textcoords="offset points",
            color="yellow",
            fontsize=8,
        )
        ax.set_title(title, fontsize=9)
    fig.suptitle(
        'Lat-long layouts: world map and camera-frame map (bundled HDRI "sunset")', fontsize=11
    )
    fig.tight_layout()
    _save(fig, path)
    return {"sun_world": d_world.tolist(), "sun_camera": d_cam.tolist()}


def _arrow3d(ax, origin, vec, color, label, scale=0.6, **kw) -> None:
    o = np.asarray(origin, float)
    v = np.asarray(vec, float) * scale
    ax.quiver(*o, *v, color=color, arrow_length_ratio=0.15, lw=2, **kw)
    ax.text(*(o + v * 1.15), label, color=color, fontsize=9)


def camera_pose_figure(path: Path) -> None:
    """A camera drawn with Blender w2c axes (left) and OpenCV c2w axes (right)."""
    w2c = ge.orbit_w2c_blender(60.0, 25.0, 2.0)
    c2w = w2c.to_c2w_opencv()
    eye = w2c.camera_position_world
    r_bl = w2c.rotation  # rows: Blender camera x, y, z axes in world coordinates
    r_cv = c2w.matrix[:3, :3]  # columns: OpenCV camera x, y, z axes in world coordinates
    fig = plt.figure(figsize=(11, 5.2))
    panels = (
        (
            "W2CBlender [R | t]  (3x4, world → camera)\nrows of R = camera axes: x right, y up, z back; "
            "looks along −z",
            [(r_bl[0], "x"), (r_bl[1], "y"), (r_bl[2], "z")],
            "−z = view",
        ),
        (
            "C2WOpenCV (4x4, camera → world)\ncolumns = camera axes: x right, y down, z forward; "
            "looks along +z",
            [(r_cv[:, 0], "x"), (r_cv[:, 1], "y"), (r_cv[:, 2], "z")],
            "+z = view",
        ),
    )
    colors = ("#d62728", "#2ca02c", "#1f77b4")
    for k, (title, axes_cam, view_label) in enumerate(panels):
        ax = fig.add_subplot(1, 2, k + 1, projection="3d")
        for vec, name, col in zip(np.eye(3), "XYZ", colors):
            _arrow3d(ax, (0, 0, 0), vec, col, f"world {name}", scale=0.8, alpha=0.5)
        for (vec, name), col in zip(axes_cam, colors):
            _arrow3d(ax, eye, vec, col, f"cam {name}", scale=0.55)
        forward = -r_bl[2]
        ax.plot(
            *np.stack([eye, eye + forward * np.linalg.norm(eye)]).T, color="grey", ls="--", lw=1
        )
        ax.text(*(eye + forward * 0.9), view_label, color="grey", fontsize=8)
        ax.scatter([0], [0], [0], color="black", s=15)
        ax.set_xlim(-0.5, 2.2)
        ax.set_ylim(-0.5, 2.2)
        ax.set_zlim(-0.5, 1.5)
        ax.set_xlabel("X")
        ax.set_ylabel("Y")
        ax.set_zlabel("Z (up)")
        ax.view_init(elev=28, azim=-75)  # camera right and forward both at ~45 degrees to the view
        ax.set_box_aspect((2.7, 2.7, 2.0))
        ax.set_title(title, fontsize=9)
    fig.suptitle(
        "One camera, two conventions: R_opencv = diag(1, −1, −1) R_blender (exact; "
        "W2CBlender.to_c2w_opencv / C2WOpenCV.to_w2c_blender)",
        fontsize=10,
    )
    fig.tight_layout()
    _save(fig, path)


# --------------------------------------------------------------------------------------------------
# Encodings
# --------------------------------------------------------------------------------------------------
def encodings_figure(env: ge.EnvironmentMap, path: Path) -> dict[str, float]:
    """The same map and pose encoded both ways, and default − compat."""
    src = ge.resize_conservative(env, 256)  # the authors' training maps were 512x256
    pose = ge.orbit_w2c_blender(FIG_AZIMUTH, FIG_ELEVATION, 2.0)
    enc = {
        mode: ge.encode_lighting(src, pose, compat=mode) for mode in ("neural-gaffer", "default")
    }
    fig, axes = plt.subplots(2, 3, figsize=(12, 8.4))
    stats = {}
    for row, kind in enumerate(("ldr", "hdr")):
        a = getattr(enc["neural-gaffer"], kind)[0].permute(1, 2, 0).numpy()
        b = getattr(enc["default"], kind)[0].permute(1, 2, 0).numpy()
        diff = (b - a).mean(axis=-1)
        lim = float(np.percentile(np.abs(diff), 99.5)) or 1e-3
        axes[row, 0].imshow(a, interpolation="nearest")
        axes[row, 1].imshow(b, interpolation="nearest")
        im = axes[row, 2].imshow(diff, cmap="RdBu_r", vmin=-lim, vmax=lim, interpolation="nearest")
        fig.colorbar(im, ax=axes[row, 2], fraction=0.046, pad=0.04)
        name = "E_L (LDR)" if kind == "ldr" else "E_H (HDR)"
        axes[row, 0].set_title(f'{name}, compat="neural-gaffer"', fontsize=9)
        axes[row, 1].set_title(f'{name}, compat="default"', fontsize=9)
        axes[row, 2].set_title(f"default − compat (mean over RGB; ±{lim:.3f} shown)", fontsize=9)
        stats[f"{kind}_mean_abs_diff"] = float(np.abs(b - a).mean())
        stats[f"{kind}_max_abs_diff"] = float(np.abs(b - a).max())
    for ax in axes.flat:
        ax.set_xticks([0, 64, 128, 192, 255])
        ax.set_xticklabels(["0", ".25", ".5", ".75", "1"], fontsize=7)
        ax.set_yticks([])
    fig.suptitle(
        f'Bundled "sunset" at 512x256, camera at azimuth {FIG_AZIMUTH:g}°, elevation {FIG_ELEVATION:g}°: '
        "256x256 encodings (u ticks)",
        fontsize=10,
    )
    fig.tight_layout()
    _save(fig, path)
    return stats


def normaliser_figure(env: ge.EnvironmentMap, path: Path) -> None:
    """HDR normaliser log1p(10 peak) of each mode for a camera going once round the object."""
    src = ge.resize_conservative(env, 256)
    azimuths = np.arange(0, 360, 10.0)
    poses = [ge.orbit_w2c_blender(a, FIG_ELEVATION, 2.0) for a in azimuths]
    rot = torch.from_numpy(np.stack([p.rotation for p in poses]))
    radiance = torch.from_numpy(np.array(src.radiance_linear))[None].expand(len(poses), -1, -1, -1)
    from gaffer_envmap.compat import rotate_neural_gaffer

    rotated = rotate_neural_gaffer(radiance, rot)
    compat_norm = torch.log1p(10 * rotated.flatten(1).amax(1)).numpy()
    default_norm = np.full_like(compat_norm, np.log1p(10 * float(src.radiance_linear.max())))
    fig, ax = plt.subplots(figsize=(7.5, 3.2))
    ax.plot(
        azimuths, compat_norm, "o-", ms=3, label="compat: max of log1p(10 E) over the ROTATED map"
    )
    ax.plot(azimuths, default_norm, "-", label="default: log1p(10 peak) of the SOURCE map")
    ax.set_xlabel("camera azimuth (degrees)")
    ax.set_ylabel("HDR normaliser")
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.22), ncol=2, frameon=False)
    ax.grid(alpha=0.3)
    ax.set_title(
        'E_H = log1p(10 E) / normaliser, for one map as the camera turns ("sunset", 512x256)',
        fontsize=9,
    )
    fig.tight_layout()
    _save(fig, path)


# --------------------------------------------------------------------------------------------------
# Tutorial: execute docs/_scripts/tutorial.py section by section, keeping each section's output.
# --------------------------------------------------------------------------------------------------
def run_tutorial(out: Path) -> list[str]:
    """Run the tutorial's sections in one namespace; write `<section>.txt` with what each printed."""
    source = (SCRIPTS / "tutorial.py").read_text()
    sections: list[tuple[str, list[str]]] = []
    for line in source.splitlines():
        if line.startswith("# [") and line.rstrip().endswith("]"):
            sections.append((line.strip()[3:-1], []))
        elif sections:
            sections[-1][1].append(line)
    namespace: dict[str, object] = {"__name__": "tutorial", "OUT": out}
    preamble = source.split("\n# [", 1)[0]
    exec(compile(preamble, "tutorial.py", "exec"), namespace)
    for name, lines in sections:
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            exec(compile("\n".join(lines), f"tutorial.py[{name}]", "exec"), namespace)
        _write(out / f"{name}.txt", buf.getvalue())
    return [name for name, _ in sections]


# --------------------------------------------------------------------------------------------------
# Benchmarks (committed baselines)
# --------------------------------------------------------------------------------------------------
def _machine_line(meta: dict) -> str:
    load = meta.get("load_average_start")
    load_s = f"; load average at start {load[0]:.1f}" if load else ""
    return (
        f"{meta['device']}; torch {meta['torch']} ({meta['torch_threads']} threads), numpy {meta['numpy']}, "
        f"Python {meta['python']}; CUDA: {meta['cuda']}; measured {meta['date_utc']}{load_s}"
    )


def bench_pages(out: Path) -> None:
    """Copy the committed benchmark PNGs and write their tables (device included)."""
    (out / "bench").mkdir(parents=True, exist_ok=True)
    pre, fil = BENCH / "envmap_preprocess.json", BENCH / "envmap_filters.json"
    if pre.exists():
        data = json.loads(pre.read_text())
        shutil.copyfile(pre.with_suffix(".png"), out / "bench" / "envmap_preprocess.png")
        rows = [
            "| variant | maps/s (median) | min – max | × theirs with the same torch threads (paired median) |",
            "|---|---|---|---|",
        ]
        for r in data["scenarios"]:
            m = r["maps_per_s"]
            rows.append(
                f"| {r['name']} | {m['median']:.1f} | {m['min']:.1f} – {m['max']:.1f} "
                f"| {r['ratio_vs_theirs']['median']:.2f} |"
            )
        t = data["targets"]
        fid = data["fidelity_theirs_vs_compat"]
        text = (
            f"**Measured on:** {_machine_line(data['machine'])}.\n\n" + "\n".join(rows) + "\n\n"
            f"Encoding vs training (issue 35): the default encodes "
            f"{t['encode_vs_training']['encode_maps_per_s']:.1f} maps/s one at a time; a gaffer-tiny "
            f"training step consumes {t['encode_vs_training']['training_envmaps_per_s']:.2f} maps/s "
            f"(ratio {t['encode_vs_training']['ratio']:.1f}). Regression guard (the earlier ratios to "
            f"theirs): {'met' if t['regression_guard']['met'] else 'not met'}. "
            f'The re-created authors\' pipeline agrees with `compat="neural-gaffer"` on '
            f"{fid['uint8_values_compared'] - fid['uint8_values_differing']:,} of "
            f"{fid['uint8_values_compared']:,} uint8 values (largest difference "
            f"{fid['max_abs_difference_lsb']} LSB).\n\n"
            "```{image} _generated/bench/envmap_preprocess.png\n:alt: Maps per second of each preprocessing variant.\n"
            ":width: 100%\n```\n"
        )
    else:
        text = "*No committed baseline yet: run `python benchmarks/bench_envmap_preprocess.py --update-baseline`.*\n"
    _write(out / "bench_preprocess.md", text)
    if fil.exists():
        data = json.loads(fil.read_text())
        shutil.copyfile(fil.with_suffix(".png"), out / "bench" / "envmap_filters.png")
        rows = [
            "| pipeline | renormalise | ms / map | power error (median / p90) "
            "| direction error, first moment (median / p90) | direction error, bright centroid (median) |",
            "|---|---|---|---|---|---|",
        ]
        for r in data["results"]:
            pe, de, dc = (
                r["power_error"],
                r["direction_error_deg_first_moment"],
                r["direction_error_deg_bright_centroid"],
            )
            rows.append(
                f"| {r['label']} | {'on' if r['renormalize'] else 'off'} | {r['ms_per_map']['median']:.1f} "
                f"| {pe['median']:.2e} / {pe['p90']:.2e} | {de['median']:.3f}° / {de['p90']:.3f}° "
                f"| {dc['median']:.3f}° |"
            )
        floor = data["source_grid_direction_floor_deg"]
        text = (
            f"**Measured on:** {_machine_line(data['machine'])}; {data['config']['suns']} suns.\n\n"
            + "\n".join(rows)
            + f"\n\nFloor set by the 512x256 source grid itself (first moment of the source map vs the "
            f"true sun direction): median {floor['median']:.3f}°.\n\n"
            "```{image} _generated/bench/envmap_filters.png\n:alt: Power error and sun-direction error against time "
            "per map, for each rotation filter.\n:width: 100%\n```\n"
        )
    else:
        text = "*No committed baseline yet: run `python benchmarks/bench_envmap_filters.py --update-baseline`.*\n"
    _write(out / "bench_filters.md", text)
    _write(out / "bench_data_render.md", bench_data_render(out))
    _write(out / "bench_diffusion.md", bench_diffusion(out))
    _write(out / "bench_nerf.md", bench_nerf(out))
    shown = {
        "envmap_preprocess",
        "envmap_filters",
        "data_render",
        "diffusion_speed",
        "diffusion_steps",
        "diffusion_quality",
        "nerf",
    }
    _write(out / "bench_other.md", bench_other_charts(out, shown))


def _chart(out: Path, name: str, alt: str) -> str:
    """Copy `results/<name>.png` beside the generated pages; the MyST block that shows it."""
    shutil.copyfile(BENCH / f"{name}.png", out / "bench" / f"{name}.png")
    return f"```{{image}} _generated/bench/{name}.png\n:alt: {alt}\n:width: 100%\n```\n"


def _missing(script: str) -> str:
    return f"*No committed baseline yet: run `python benchmarks/{script} --update-baseline`.*\n"


def _render_setting(p: dict) -> str:
    den = "denoiser" if p["denoise"] else "no denoiser"
    ada = f", adaptive threshold {p['adaptive_threshold']:g}" if p["adaptive_threshold"] else ""
    return f"{p['resolution']} px, {p['samples']} spp, {den}{ada}"


def bench_data_render(out: Path) -> str:
    """The Cycles render benchmark: headline numbers, chart, every setting."""
    path = BENCH / "data_render.json"
    if not path.exists():
        return _missing("bench_data_render.py")
    d = json.loads(path.read_text())
    a, f = d["authors_setting_128spp_denoised"], d["fastest_reaching_authors_quality"]
    rows = [
        "| resolution | spp | denoiser | adaptive threshold | s / image | PSNR vs reference (dB) |",
        "|---|---|---|---|---|---|",
    ]
    for p in d["points"]:
        rows.append(
            f"| {p['resolution']} | {p['samples']} | {'on' if p['denoise'] else 'off'} "
            f"| {p['adaptive_threshold']:g} | {p['seconds_per_image']:.2f} | {p['psnr_db']:.1f} |"
        )
    return (
        f"**Measured on:** {_machine_line(d['machine'])}; Blender Cycles on {d['cores']} cores, "
        f"{d['images_per_setting']} images per setting.\n\n"
        f"Headline: the authors' setting ({_render_setting(a)}) takes {a['seconds_per_image']:.2f} s "
        f"per image at {a['psnr_db']:.1f} dB against the high-sample reference; the fastest setting that "
        f"reaches that quality is {_render_setting(f)}: {f['seconds_per_image']:.2f} s per image at "
        f"{f['psnr_db']:.1f} dB ({a['seconds_per_image'] / f['seconds_per_image']:.1f}x faster).\n\n"
        + _chart(out, "data_render", "Cycles seconds per image against PSNR, per sample count.")
        + "\n"
        + "\n".join(rows)
        + "\n"
    )


def bench_diffusion(out: Path) -> str:
    """The diffusion benchmarks: full-size model latency (CPU) and sampler steps vs accuracy."""
    text = ""
    path = BENCH / "diffusion_speed.json"
    if path.exists():
        d = json.loads(path.read_text())
        cfg = d["config"]
        rows = ["| operation (CPU) | batch | seconds (min) |", "|---|---|---|"]
        for r in d["cpu"]:
            rows.append(f"| {r['op']} | {r['batch']} | {r['seconds']['min']:.2f} |")
        text += (
            "### Full-size model latency\n\n"
            f"**Measured on:** {_machine_line(d['machine'])}; {cfg['model']}, {cfg['cpu_dtype']}, "
            f"attention {cfg['attention']}.\n\n"
            + "\n".join(rows)
            + f"\n\nGPU part: {d['cuda']}.\n\n"
            + _chart(out, "diffusion_speed", "Per-operation CPU latency of the full-size model.")
            + "\n"
        )
    else:
        text += _missing("bench_diffusion.py")
    path = BENCH / "diffusion_steps.json"
    if path.exists():
        d = json.loads(path.read_text())
        cfg = d["config"]
        by: dict[str, dict[int, dict]] = {}
        for r in d["rows"]:
            by.setdefault(r["scheduler"], {})[r["steps"]] = r
        steps = sorted({r["steps"] for r in d["rows"]})
        head = "| steps | " + " | ".join(f"{s}: PSNR (dB) / ms per image" for s in by) + " |"
        rows = [head, "|---" * (len(by) + 1) + "|"]
        for n in steps:
            cells = []
            for s in by:
                r = by[s].get(n)
                psnr = r and r["psnr_vs_ddim50"]
                cells.append(
                    "-"
                    if r is None
                    else f"{'reference' if psnr == 'inf' else f'{psnr:.1f}'} / "
                    f"{1000 * r['s_per_image']:.0f}"
                )
            rows.append(f"| {n} | " + " | ".join(cells) + " |")
        text += (
            "### Sampler steps\n\n"
            f"**Measured on:** {_machine_line(d['machine'])}; {cfg['model']}, batch {cfg['batch']}, "
            f"guidance {cfg['guidance_scale']:g}; accuracy = distance to {cfg['reference']}.\n\n"
            + "\n".join(rows)
            + f"\n\nCaveat recorded with the numbers: {cfg['caveat']}.\n\n"
            + _chart(
                out, "diffusion_steps", "Seconds per image against PSNR to DDIM-50, per sampler."
            )
        )
    else:
        text += _missing("bench_diffusion.py")
    path = BENCH / "diffusion_quality.json"
    if path.exists():
        d = json.loads(path.read_text())
        cfg, base = d["config"], d["baselines"]
        rows = [
            "| sampler | steps | object PSNR (dB) | object PSNR aligned (dB) | full-frame PSNR "
            "(dB) | full-frame SSIM | ms per image |",
            "|---|---|---|---|---|---|---|",
        ]

        def db(v: float | None) -> str:
            return "n/a" if v is None else f"{v:.2f}"

        for r in d["rows"]:
            rows.append(
                f"| {r['scheduler']} | {r['steps']} | {db(r.get('object_psnr'))} | "
                f"{db(r.get('object_psnr_aligned'))} | {r['psnr']:.2f} | {r['ssim']:.3f} | "
                f"{1000 * r['s_per_image']:.0f} |"
            )
        obj = base.get("unrelit_input_object_psnr")
        obj_al = base.get("unrelit_input_object_psnr_aligned")
        # the model the record measured (issue 34): release and UNet weights' sha256, when recorded
        model = d.get("model")
        if isinstance(model, dict):
            unet = next((v for k, v in model["weights_sha256"].items() if "/unet/" in k), "")
            measured = f"{model['name']} {model['version']} (UNet sha256 {unet[:12]})"
            if not model.get("shipped"):
                measured += ", not the shipped model"
        else:
            measured = f"{cfg['model']} (weights not recorded: an older model)"
        text += (
            "\n### gaffer-tiny: relighting quality against sampling time\n\n"
            f"**Measured on:** {_machine_line(d['machine'])}; {measured}, {cfg['data']}, "
            f"{cfg['pairs']} pairs, guidance {cfg['guidance_scale']:g}, against ground-truth renders. "
            f"Baselines over the object mask: the unrelit input {db(obj)} dB, the input "
            f"channel-aligned to the target {db(obj_al)} dB (full frame: "
            f"{base['unrelit_input_psnr']:.2f} / {base['input_aligned_to_target_psnr']:.2f} dB).\n\n"
            + "\n".join(rows)
            + "\n\n"
            + _chart(
                out,
                "diffusion_quality",
                "gaffer-tiny object-mask PSNR against milliseconds per image, per sampler and "
                "step count.",
            )
        )
    else:
        text += _missing("bench_diffusion.py --part quality")
    return text


def bench_nerf(out: Path) -> str:
    """The NeRF benchmark: grid sizing (fit) and the relighting stages."""
    path = BENCH / "nerf.json"
    if not path.exists():
        return _missing("bench_nerf.py")
    d = json.loads(path.read_text())
    rows = ["| fit | seconds | final grid | grid MiB | test PSNR (dB, input lighting) |"]
    rows.append("|---|---|---|---|---|")
    for r in d["fits"]:
        rows.append(
            f"| {r['label']} | {r['seconds']:.1f} | {'x'.join(map(str, r['final_grid']))} "
            f"| {r['grid_mib']:.3f} | {r['test_psnr_db']:.2f} |"
        )
    rel = d["relight"]
    full = rel["full_relight_random_model"]
    phases = ", ".join(f"{k} {v:.2f} s" for k, v in full["phase_seconds"].items())
    s1 = [
        "| Stage 1, oracle relit views | seconds | test PSNR (dB, target lighting) |",
        "|---|---|---|",
    ]
    s1.append(
        f"| input field, not relit | - | {rel['input_field_vs_target']['test_psnr_db']:.2f} |"
    )
    for r in rel["stage1_oracle"]:
        s1.append(
            f"| {r['iterations']} iterations | {r['seconds']:.1f} | {r['test_psnr_db']:.2f} |"
        )
    fits = {r["label"]: r for r in d["fits"]}
    fixed = fits.get("fixed 32^3")
    best = max(d["fits"], key=lambda r: r["test_psnr_db"])
    headline = (
        f"Headline: the tiny preset's fixed 32^3 grid fits in {fixed['seconds']:.1f} s to "
        f"{fixed['test_psnr_db']:.2f} dB; the best test PSNR here is {best['label']} "
        f"({best['test_psnr_db']:.2f} dB in {best['seconds']:.1f} s, {best['grid_mib']:.3f} MiB). "
        if fixed
        else ""
    )
    last = rel["stage1_oracle"][-1]
    return (
        f"**Measured on:** {_machine_line(d['machine'])}; {d['config']['scene']}; one run per row.\n\n"
        + headline
        + f"Stage 1 with oracle relit views lifts the test PSNR under the target lighting from "
        f"{rel['input_field_vs_target']['test_psnr_db']:.1f} dB (not relit) to "
        f"{last['test_psnr_db']:.1f} dB in {last['seconds']:.1f} s ({last['iterations']} iterations).\n\n"
        + _chart(out, "nerf", "Fit seconds against test PSNR per grid; relighting phase timings.")
        + "\n"
        + "\n".join(rows)
        + f"\n\nThe whole `relight_field` with the tiny random diffusion model (timings only): {phases}; "
        f"total {full['total_seconds']:.1f} s.\n\n" + "\n".join(s1) + "\n"
    )


def bench_other_charts(out: Path, shown: set[str]) -> str:
    """Any committed chart that no section above shows (so the page always gathers every chart)."""
    text = ""
    for png in sorted(BENCH.glob("*.png")):
        if png.stem in shown:
            continue
        meta = {}
        if png.with_suffix(".json").exists():
            meta = json.loads(png.with_suffix(".json").read_text()).get("machine", {})
        where = f"**Measured on:** {_machine_line(meta)}.\n\n" if meta and "device" in meta else ""
        text += f"### `{png.stem}`\n\n{where}" + _chart(out, png.stem, png.stem) + "\n"
    return text or "*(none)*\n"


# --------------------------------------------------------------------------------------------------
# API pages
# --------------------------------------------------------------------------------------------------
API_PACKAGES = {
    "gaffer_envmap": (
        "gaffer-envmap",
        "The lighting math: env-map I/O, named lat-long conventions, camera poses, rotation into a camera "
        "frame, the model's LDR / log-HDR encodings, solid-angle-exact resampling, augmentation and "
        "spherical harmonics.",
    ),
    "gaffer_data": (
        "gaffer-data",
        "Object filtering, Blender Cycles rendering of relighting datasets (`gaffer_data.render`, the only "
        "place that imports `bpy`; mocked for these pages) and the pure, typed dataset reader.",
    ),
    "gaffer_diffusion": (
        "gaffer-diffusion",
        "The relighting diffusion model: configs, model construction and loading, conditioning, the "
        "sampling pipeline and schedulers, metrics, evaluation, training (extra `[train]`) and the CLI.",
    ),
    "gaffer_nerf": (
        "gaffer-nerf",
        "Relighting radiance fields: TensoRF fitting with fixed or footprint-sized grids, the diffusion "
        "guide, Stage 1 (relit views) and Stage 2 (guided refinement), evaluation and the CLI.",
    ),
}


def public_modules(package: str = "gaffer_envmap") -> list[str]:
    """Every public module of `package`, subpackages included (no `_private` part, no `__main__`)."""
    root = importlib.import_module(package)
    return sorted(
        m.name
        for m in pkgutil.walk_packages(root.__path__, f"{package}.")
        if not any(part.startswith("_") for part in m.name.split(".")[1:])
    )


def _private_reexports(package: str, seen: set[int]) -> list[str]:
    """autodoc directives for the names `package` re-exports from its private (`_x`) modules.

    Those modules have no page of their own, so the objects are documented under the package's name
    (autodoc records the private path as the canonical name, so references to it resolve here too).
    An object re-exported at several levels is documented once, at the first one asked (`seen`).
    """
    mod = importlib.import_module(package)
    out = []
    for name in getattr(mod, "__all__", ()):
        obj = getattr(mod, name, None)
        home = getattr(obj, "__module__", None) or ""
        if not (isinstance(obj, type) or callable(obj)) or not home.startswith(package + "."):
            continue
        if not any(part.startswith("_") for part in home[len(package) + 1 :].split(".")):
            continue
        if id(obj) in seen:
            continue
        seen.add(id(obj))
        directive = "autoclass" if isinstance(obj, type) else "autofunction"
        out.append(f".. {directive}:: {package}.{name}")
    return out


def _api_index(package: str) -> str:
    """A table of the package's re-exports (`__all__`), each linked to the module that defines it."""
    root = importlib.import_module(package)
    rows = ["| name | kind | defined in |", "|---|---|---|"]
    for name in getattr(root, "__all__", ()):
        if name.startswith("__"):
            continue
        obj = getattr(root, name)
        mod = getattr(obj, "__module__", None)
        if isinstance(obj, type) or callable(obj):
            kind = "class" if isinstance(obj, type) else "function"
            if mod is None or not mod.startswith(package):
                rows.append(f"| `{name}` | {kind} | |")
                continue
            if "._" in mod:  # documented under a package's name (see `_private_reexports`)
                role = "py:class" if kind == "class" else "py:func"
                rows.append(f"| {{{role}}}`~{mod}.{name}` | {kind} | a private module |")
                continue
            role = "py:class" if kind == "class" else "py:func"
            rows.append(f"| {{{role}}}`~{mod}.{name}` | {kind} | {{py:mod}}`{mod}` |")
        else:
            home = next(
                (
                    m
                    for m in public_modules(package)
                    if name in vars(importlib.import_module(m))
                    and vars(importlib.import_module(m))[name] is obj
                ),
                None,
            )
            where = f"{{py:mod}}`{home}`" if home else ""
            rows.append(f"| `{name}` | {type(obj).__name__} | {where} |")
    return "\n".join(rows) + "\n"


def api_pages(out: Path) -> None:
    """Per package: a page with its re-exports and one autodoc page per public module."""
    api = out / "api"
    api.mkdir(parents=True, exist_ok=True)
    wanted: set[Path] = set()
    seen: set[int] = set()
    for package, (dist, blurb) in API_PACKAGES.items():
        modules = public_modules(package)
        for mod in modules:
            page = api / package / f"{mod}.md"
            wanted.add(page)
            # A subpackage's `__all__` re-exports its modules' names: document only what it defines,
            # so every object has exactly one page (the re-exports are listed on the package page).
            is_pkg = hasattr(importlib.import_module(mod), "__path__")
            opts = "   :ignore-module-all:\n" if is_pkg else ""
            extra = "".join(f"\n{d}\n" for d in _private_reexports(mod, seen)) if is_pkg else ""
            _write(page, f"# `{mod}`\n\n```{{eval-rst}}\n.. automodule:: {mod}\n{opts}{extra}```\n")
        page = api / f"{package}.md"
        wanted.add(page)
        _write(
            page,
            f"# {dist}\n\n{blurb}\n\n`import {package}` re-exports the names below; each module "
            "of the package has a page of its own, generated from its docstrings.\n\n"
            + _api_index(package)
            + (
                "\n## Defined in private modules\n\n```{eval-rst}\n"
                + "\n\n".join(private)
                + "\n```\n"
                if (private := _private_reexports(package, seen))
                else ""
            )
            + "\n```{toctree}\n:maxdepth: 1\n:caption: Modules\n\n"
            + "\n".join(f"{package}/{mod}" for mod in modules)
            + "\n```\n",
        )
    for stale in api.rglob("*.md"):
        if stale not in wanted:
            stale.unlink()


# --------------------------------------------------------------------------------------------------
def main(out: Path | None = None, quiet: bool = False) -> None:
    out = Path(out) if out is not None else DOCS / "_generated"
    out.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(max(1, torch.get_num_threads()))
    env = load_sunset()
    _write(out / "conventions_table.md", conventions_table())
    facts = conventions_figure(env, out / "conventions.png")
    camera_pose_figure(out / "camera_poses.png")
    facts |= encodings_figure(env, out / "encodings.png")
    normaliser_figure(env, out / "normaliser.png")
    _write(out / "facts.json", json.dumps(facts, indent=2) + "\n")
    sections = run_tutorial(out / "tutorial")
    bench_pages(out)
    api_pages(out)
    checked = importlib.import_module("check_commands").check(DOCS)
    if not quiet:
        print(
            f"generated under {out}: tutorial sections {sections}; {checked} CLI commands checked"
        )


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DOCS / "_generated")
    main(parser.parse_args().out)
