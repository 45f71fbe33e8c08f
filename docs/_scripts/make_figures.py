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
- `api/*.md`: one autodoc page per public module of gaffer_envmap; `api_index.md`: the re-exports.
"""

import argparse
import contextlib
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
            f"Targets: default ≥ {t['default_vs_theirs']['target']:g}× theirs: best measured "
            f"{t['default_vs_theirs']['best_measured']:.2f}× ({'met' if t['default_vs_theirs']['met'] else 'not met'}); "
            f"compat ≥ {t['compat_vs_theirs']['target']:g}× theirs: worst measured "
            f"{t['compat_vs_theirs']['worst_measured']:.2f}× ({'met' if t['compat_vs_theirs']['met'] else 'not met'}). "
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


# --------------------------------------------------------------------------------------------------
# API pages
# --------------------------------------------------------------------------------------------------
def public_modules() -> list[str]:
    return sorted(
        f"gaffer_envmap.{m.name}"
        for m in pkgutil.iter_modules(ge.__path__)
        if not m.name.startswith("_") and m.name != "__main__"
    )


def api_pages(out: Path) -> None:
    """One page per public module, and a table of the package's re-exports linking to them."""
    api = out / "api"
    api.mkdir(parents=True, exist_ok=True)
    modules = public_modules()
    for stale in api.glob("*.md"):
        if stale.stem not in modules:
            stale.unlink()
    for mod in modules:
        _write(api / f"{mod}.md", f"# `{mod}`\n\n```{{eval-rst}}\n.. automodule:: {mod}\n```\n")
    rows = ["| name | kind | defined in |", "|---|---|---|"]
    for name in ge.__all__:
        obj = getattr(ge, name)
        mod = getattr(obj, "__module__", None)
        if name == "__version__" or mod is None or not mod.startswith("gaffer_envmap"):
            if name == "CONVENTIONS":
                rows.append("| `CONVENTIONS` | registry | {py:mod}`gaffer_envmap.conventions` |")
            elif name == "IDENTITY_LAYOUT_W2C":
                rows.append("| `IDENTITY_LAYOUT_W2C` | constant | {py:mod}`gaffer_envmap.poses` |")
            continue
        kind = "class" if isinstance(obj, type) else "function" if callable(obj) else "object"
        role = "py:class" if kind == "class" else "py:func" if kind == "function" else "py:data"
        rows.append(f"| {{{role}}}`~{mod}.{name}` | {kind} | {{py:mod}}`{mod}` |")
    _write(out / "api_index.md", "\n".join(rows) + "\n")


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
    if not quiet:
        print(f"generated under {out}: tutorial sections {sections}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DOCS / "_generated")
    main(parser.parse_args().out)
