"""Speed vs accuracy of the rotation filters, measured on disc suns under random camera rotations.

Every pipeline turns a 512x256 Blender-convention world map holding one disc sun (radius 0.5-2 degrees,
uniformly random direction, so a random sub-pixel position; black sky) into a 256x256 camera-frame map
(layout "neural-gaffer-camera") for a uniformly random world-to-camera rotation R. Pipelines:

- `bilinear`: `rotate_to_camera(filter="bilinear")`;
- `conservative ss1, ss2`: `rotate_to_camera(filter="conservative", supersample=s)`; ss2 is the
  power-exact default (torch path, the fused kernel serves `encode_lighting` only);
- `area ss1..ss4`: `rotate_to_camera(filter="area", supersample=s)` (with this source and output size the
  pre-downsample has nothing to do, so ss1 may coincide with bilinear; the JSON records whether it does);
- `compat linear`: the authors' geometry on linear radiance: `compat.rotate_neural_gaffer` at source
  resolution (align_corners=True, zero padding), then PIL bilinear 512x256 -> 256x256 (float, no 8-bit);
- `compat 8-bit`: `encode_lighting(compat="neural-gaffer")` itself; its HDR map decoded back to
  radiance with the rotated map's peak (which the authors' pipeline divides out and does not store).

Each runs with renormalisation off and on. "On" is `renormalize=True` for the area filter; for the
others the benchmark applies the same global rescale (output power := source power) itself. A global
scale cannot move the mean light direction, so only the power error changes.

Measured per map: time (interleaved repetitions over a batch); |P_out / P_in - 1| with P = sum(L * Omega)
over each grid; and the angle between R @ d_sun_world and (i) the output's mean light direction (first
moment, sum(L * Omega * d_cam) over the 256x256 grid) and (ii) the centroid of its brightest pixels
(luminance >= half the peak). And per pipeline, a constant map (radiance 1) through the first 4 rotations:
max and rms |out - 1| (a filter's own texture, e.g. the conservative filter's per-texel gain ripple). Results: JSON + PNG under benchmarks/results/ (benchmarks/README.md).

Run: `python benchmarks/bench_envmap_filters.py [--quick] [--update-baseline]`.
"""

import sys
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any, Literal

import _common as common
import numpy as np
import torch
from PIL import Image

import gaffer_envmap as ge
from gaffer_envmap.compat import rotate_neural_gaffer
from gaffer_envmap.stats import first_moment
from gaffer_envmap.testing import angle_deg, disc_sun_map

NAME = "envmap_filters"
SRC_HEIGHT = 256
OUT = 256
SUN_RADIANCE = 1000.0
RADIUS_DEG = (0.5, 2.0)

Pipeline = Literal["bilinear", "area", "conservative", "compat linear", "compat 8-bit"]


@dataclass(frozen=True, kw_only=True)
class Config:
    """One pipeline setting."""

    pipeline: Pipeline
    supersample: int = 1
    renormalize: bool = False

    @property
    def label(self) -> str:
        if self.pipeline in ("area", "conservative"):
            return f"{self.pipeline} ss{self.supersample}"
        return self.pipeline

    @property
    def name(self) -> str:
        return f"{self.label}, renorm {'on' if self.renormalize else 'off'}"


def configs() -> list[Config]:
    out = []
    for renorm in (False, True):
        out.append(Config(pipeline="bilinear", renormalize=renorm))
        out += [Config(pipeline="area", supersample=s, renormalize=renorm) for s in (1, 2, 3, 4)]
        out.append(Config(pipeline="compat linear", renormalize=renorm))
        out.append(Config(pipeline="compat 8-bit", renormalize=renorm))
    # Power-exact by construction: renormalisation would change nothing, so it is measured once.
    out += [Config(pipeline="conservative", supersample=s) for s in (1, 2)]
    return out


# ---------------------------------------------------------------------------------------------
# Grids and integrals
# ---------------------------------------------------------------------------------------------
OMEGA_SRC = torch.from_numpy(ge.row_solid_angle(SRC_HEIGHT, 2 * SRC_HEIGHT))  # [He] float64
OMEGA_OUT = torch.from_numpy(ge.row_solid_angle(OUT, OUT))  # [256]: a 256x256 grid is not 2:1
DIRS_OUT = torch.from_numpy(
    ge.direction_grid(OUT, OUT, "neural-gaffer-camera")
)  # [256, 256, 3] camera frame
LUMA = torch.tensor([0.2126, 0.7152, 0.0722], dtype=torch.float64)


def power(radiance: torch.Tensor, omega: torch.Tensor) -> torch.Tensor:
    """`[B, 3]` sum(L * Omega) of `[B, H, W, 3]` maps with row solid angles `[H]`."""
    return (radiance.double() * omega[None, :, None, None]).sum(dim=(1, 2))


def renormalize_to(out: torch.Tensor, p_src: torch.Tensor) -> torch.Tensor:
    """Global per-channel rescale so the output power equals `p_src` `[B, 3]` (the benchmark's own)."""
    p_out = power(out, OMEGA_OUT)
    scale = torch.where(p_out > 0, p_src / p_out.clamp_min(1e-300), torch.ones_like(p_out))
    return (out.double() * scale[:, None, None, :]).float()


def first_moment_camera(radiance: torch.Tensor) -> torch.Tensor:
    """`[B, 3]` luminance first moment sum(Y * Omega * d_cam) of `[B, 256, 256, 3]` camera-frame maps."""
    y = radiance.double() @ LUMA  # [B, H, W]
    return torch.einsum("bhw,h,hwc->bc", y, OMEGA_OUT, DIRS_OUT)


def bright_centroid_camera(radiance: torch.Tensor) -> torch.Tensor:
    """`[B, 3]` direction of the Omega * Y weighted centroid of the pixels at >= half the peak luminance."""
    y = radiance.double() @ LUMA
    peak = y.flatten(1).amax(1)[:, None, None]
    w = torch.where(y >= 0.5 * peak, y, torch.zeros_like(y)) * OMEGA_OUT[None, :, None]
    return torch.einsum("bhw,hwc->bc", w, DIRS_OUT)


# ---------------------------------------------------------------------------------------------
# Pipelines: world maps [B, 256, 512, 3] + rotations [B, 3, 3] -> camera-frame radiance [B, 256, 256, 3]
# ---------------------------------------------------------------------------------------------
def _pil_squash(rotated: torch.Tensor) -> torch.Tensor:
    """The authors' 2:1 -> 1:1 PIL bilinear resize, on float32 linear radiance (mode "F", per channel)."""
    arr = rotated.numpy()
    out = np.empty((arr.shape[0], OUT, OUT, 3), np.float32)
    for b in range(arr.shape[0]):
        for c in range(3):
            img = Image.fromarray(np.ascontiguousarray(arr[b, :, :, c]), mode="F")
            out[b, :, :, c] = np.asarray(img.resize((OUT, OUT), Image.BILINEAR))
    return torch.from_numpy(out)


def _decode_compat_hdr(hdr01: torch.Tensor, rotated_peak: torch.Tensor) -> torch.Tensor:
    """Invert E_H = log1p(10 E) / log1p(10 peak): `[B, 3, S, S]` in [0, 1] -> `[B, S, S, 3]` radiance."""
    log_peak = torch.log1p(10 * rotated_peak.double())[:, None, None, None]
    return (torch.expm1(hdr01.double() * log_peak) / 10).permute(0, 2, 3, 1).float()


def make_pipeline(cfg: Config) -> Callable[[torch.Tensor, np.ndarray, torch.Tensor], torch.Tensor]:
    """fn(maps, rotations, source power `[B, 3]`) -> camera-frame radiance `[B, 256, 256, 3]`."""

    def run(src: torch.Tensor, rot: np.ndarray, p_src: torch.Tensor) -> torch.Tensor:
        if cfg.pipeline == "area":
            return ge.rotate_to_camera(
                src,
                rot,
                height=OUT,
                width=OUT,
                filter="area",
                supersample=cfg.supersample,
                renormalize=cfg.renormalize,
                pairing="zip",
            )
        if cfg.pipeline == "conservative":
            return ge.rotate_to_camera(
                src,
                rot,
                height=OUT,
                width=OUT,
                filter="conservative",
                supersample=cfg.supersample,
                pairing="zip",
            )
        if cfg.pipeline == "bilinear":
            out = ge.rotate_to_camera(
                src, rot, height=OUT, width=OUT, filter="bilinear", pairing="zip"
            )
        elif cfg.pipeline == "compat linear":
            out = _pil_squash(rotate_neural_gaffer(src, torch.from_numpy(rot)))
        else:  # compat 8-bit
            enc = ge.encode_lighting(src, rot, size=OUT, compat="neural-gaffer")
            # The rotated map's peak: the normaliser the authors divide out (not part of the timed work
            # in their pipeline either, which never decodes). Computed here so radiance can be compared.
            peak = rotate_neural_gaffer(src, torch.from_numpy(rot)).flatten(1).amax(1)
            return (
                _decode_compat_hdr(enc.hdr, peak)
                if not cfg.renormalize
                else renormalize_to(_decode_compat_hdr(enc.hdr, peak), p_src)
            )
        return renormalize_to(out, p_src) if cfg.renormalize else out

    return run


# ---------------------------------------------------------------------------------------------
def make_suns(
    count: int, rng: np.random.Generator
) -> tuple[torch.Tensor, np.ndarray, np.ndarray, np.ndarray]:
    """Disc-sun world maps `[N, 256, 512, 3]`, sun directions `[N, 3]` (world), radii `[N]`, and the source
    maps' own first-moment direction errors `[N]` (degrees; the floor set by the 512x256 grid)."""
    dirs = rng.normal(size=(count, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    radii = rng.uniform(*RADIUS_DEG, size=count)
    maps, floor = [], []
    for d, r in zip(dirs, radii):
        env = disc_sun_map(SRC_HEIGHT, d, float(r), SUN_RADIANCE, sky=0.0, supersample=4)
        maps.append(np.array(env.radiance_linear))
        floor.append(angle_deg(first_moment(env), d))
    return torch.from_numpy(np.stack(maps)), dirs, radii, np.array(floor)


def summary(values: np.ndarray) -> dict[str, float]:
    v = np.asarray(values, np.float64)
    return {
        "median": float(np.median(v)),
        "p10": float(np.percentile(v, 10)),
        "p90": float(np.percentile(v, 90)),
        "max": float(v.max()),
    }


def evaluate(
    cfg: Config, suns: torch.Tensor, rots: np.ndarray, dirs_world: np.ndarray, chunk: int
) -> dict[str, Any]:
    """Errors of one pipeline over every sun."""
    run = make_pipeline(cfg)
    p_err, d_mom, d_cen = [], [], []
    for i in range(0, len(suns), chunk):
        src, rot = suns[i : i + chunk], rots[i : i + chunk]
        p_src = power(src, OMEGA_SRC)
        out = run(src, rot, p_src)
        p_out = power(out, OMEGA_OUT)
        p_err += (p_out[:, 0] / p_src[:, 0] - 1).abs().tolist()
        true_cam = np.einsum("bij,bj->bi", rot, dirs_world[i : i + chunk])  # d_cam = R d_world
        for t, m, c in zip(
            true_cam, first_moment_camera(out).numpy(), bright_centroid_camera(out).numpy()
        ):
            d_mom.append(angle_deg(m, t))
            d_cen.append(angle_deg(c, t))
    # A flat map must stay flat: a filter's own texture (the conservative filter's per-texel gain
    # ripples where texels are read unevenly) shows here and nowhere else. Same rotations, value 1.
    n_flat = min(FLAT_POSES, len(suns))
    flat = torch.ones((n_flat, *suns.shape[1:]), dtype=suns.dtype)
    dev = (run(flat, rots[:n_flat], power(flat, OMEGA_SRC)).double() - 1.0).abs()
    return {
        "power_error": summary(np.array(p_err)),
        "direction_error_deg_first_moment": summary(np.array(d_mom)),
        "direction_error_deg_bright_centroid": summary(np.array(d_cen)),
        "flat_map_deviation": {
            "max": float(dev.max()),
            "rms": float(dev.pow(2).mean().sqrt()),
            "p99": float(torch.quantile(dev.flatten()[:: max(1, dev.numel() // 2_000_000)], 0.99)),
            "poses": n_flat,
        },
    }


FLAT_POSES = 4
"""Poses of the flat-map check (a constant map of radiance 1 through each pipeline)."""


def time_per_map(
    cfgs: list[Config], suns: torch.Tensor, rots: np.ndarray, batch: int, reps: int
) -> dict[str, list[float]]:
    """Milliseconds per map, one batch per repetition, configurations interleaved (order rotated)."""
    src, rot = suns[:batch], rots[:batch]
    p_src = power(src, OMEGA_SRC)
    runs = {c.name: make_pipeline(c) for c in cfgs}
    for c in cfgs:  # warm-up (caches, allocator)
        runs[c.name](src, rot, p_src)
    ms: dict[str, list[float]] = {c.name: [] for c in cfgs}
    for rep in range(reps):
        k = rep % len(cfgs)
        for c in cfgs[k:] + cfgs[:k]:
            seconds = common.time_calls(lambda c=c: runs[c.name](src, rot, p_src), 1)
            ms[c.name].append(1e3 * seconds / batch)
    return ms


def check_first_moment_helper(rng: np.random.Generator) -> float:
    """Our 256x256 first moment against `stats.first_moment` on a 2:1 camera-frame map (must agree)."""
    arr = rng.random((OUT // 2, OUT, 3)).astype(np.float32)
    env = ge.EnvironmentMap(radiance_linear=arr, convention="neural-gaffer-camera")
    ref = first_moment(env)
    y = torch.from_numpy(arr).double() @ LUMA
    om = torch.from_numpy(ge.row_solid_angle(OUT // 2, OUT))
    dirs = torch.from_numpy(ge.direction_grid(OUT // 2, OUT, "neural-gaffer-camera"))
    ours = torch.einsum("hw,h,hwc->c", y, om, dirs).numpy()
    return float(np.abs(ours - ref).max() / np.abs(ref).max())


def plot(rows: list[dict[str, Any]], meta: dict[str, Any], quick: bool, floor_deg: float) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FormatStrFormatter
    from matplotlib.transforms import blended_transform_factory

    colors = {
        "bilinear": "#2ca02c",
        "area ss1": "#fdae6b",
        "area ss2": "#f16913",
        "area ss3": "#d94801",
        "area ss4": "#8c2d04",
        "compat linear": "#6baed6",
        "compat 8-bit": "#08519c",
        "conservative ss1": "#b15928",
        "conservative ss2": "#6a3d9a",
    }
    fig, (ax_p, ax_d) = plt.subplots(2, 1, figsize=(11.0, 8.5), sharex=True)
    floor_p = 1e-9
    for r in rows:
        x = r["ms_per_map"]["median"]
        xerr = [[x - r["ms_per_map"]["q25"]], [r["ms_per_map"]["q75"] - x]]
        filled = r["renormalize"]
        style = dict(
            color=colors[r["label"]],
            marker="o" if r["pipeline"] != "bilinear" else "s",
            ms=7,
            mfc=colors[r["label"]] if filled else "white",
            mew=1.6,
            capsize=2,
            lw=1,
        )
        pe = r["power_error"]
        yp = max(pe["median"], floor_p)
        ax_p.errorbar(
            x,
            yp,
            xerr=xerr,
            yerr=[[yp - max(pe["p10"], floor_p)], [max(pe["p90"], floor_p) - yp]],
            label=r["name"],
            **style,
        )
        if not r["renormalize"]:  # a global rescale leaves the direction unchanged: plot it once
            de = r["direction_error_deg_first_moment"]
            ax_d.errorbar(
                x,
                de["median"],
                xerr=xerr,
                yerr=[[de["median"] - de["p10"]], [de["p90"] - de["median"]]],
                label=r["label"],
                **{**style, "mfc": colors[r["label"]]},
            )
    half_px = 180.0 / OUT / 2
    ax_d.axhline(half_px, color="grey", ls="--", lw=1)
    ax_d.text(
        0.01,
        half_px * 1.08,
        f"1/2 output pixel in v ({half_px:.2f} deg)",
        color="grey",
        fontsize=8,
        transform=blended_transform_factory(ax_d.transAxes, ax_d.transData),
    )
    ax_d.axhline(floor_deg, color="lightgrey", ls=":", lw=1)
    ax_d.text(
        0.01,
        floor_deg * 1.08,
        f"source grid's own error, median ({floor_deg:.3f} deg)",
        color="grey",
        fontsize=8,
        transform=blended_transform_factory(ax_d.transAxes, ax_d.transData),
    )
    ax_p.axhline(floor_p, color="lightgrey", lw=0.8)
    ax_p.set_yscale("log")
    ax_p.set_ylabel("|P_out / P_in - 1|  (median, bars p10-p90)")
    ax_p.set_title("total power error (hollow: renormalisation off, filled: on)", fontsize=9)
    ax_p.legend(
        fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), title="pipeline", title_fontsize=8
    )
    ax_d.set_yscale("log")
    ax_d.set_xscale("log")
    ax_d.xaxis.set_major_formatter(FormatStrFormatter("%g"))
    ax_d.xaxis.set_minor_formatter(FormatStrFormatter("%g"))
    ax_d.tick_params(axis="x", which="minor", labelsize=7)
    ax_d.set_xlabel("time per map, ms (median over repetitions; bars: interquartile range)")
    ax_d.set_ylabel("sun direction error, degrees (first moment)")
    ax_d.set_title("angle between the output's mean light direction and R d_sun", fontsize=9)
    ax_d.legend(
        fontsize=7,
        loc="upper left",
        bbox_to_anchor=(1.01, 1.0),
        title="(renorm. cannot move it)",
        title_fontsize=7,
    )
    for ax in (ax_p, ax_d):
        ax.grid(which="both", alpha=0.25)
    mode = " (--quick)" if quick else ""
    fig.suptitle(
        f"Rotation filters: disc suns (r = 0.5-2 deg), 512x256 world -> 256x256 camera map{mode}\n"
        f"{common.short_device(meta)}",
        fontsize=10,
    )
    fig.tight_layout()
    return fig


def readme_table(payload: dict[str, Any]) -> str:
    """The baseline's numbers as the Markdown block of benchmarks/README.md."""
    m = payload["machine"]
    lines = [
        f"Measured {m['date_utc']} on {m['device']}, torch {m['torch']} ({m['torch_threads']} threads); "
        f"load average {m['load_average_start'][0]:.1f} at start, {m['load_average_end'][0]:.1f} at end; "
        f"{payload['config']['suns']} suns, timing batches of {payload['config']['timing_batch']}.",
        "",
        "| pipeline | renorm | ms/map | power error median / p90 | direction error (first moment) "
        "median / p90 | direction error (bright centroid) median | flat map max / rms deviation |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in payload["results"]:
        pe = r["power_error"]
        de = r["direction_error_deg_first_moment"]
        dc = r["direction_error_deg_bright_centroid"]
        lines.append(
            f"| {r['label']} | {'on' if r['renormalize'] else 'off'} | {r['ms_per_map']['median']:.1f} "
            f"| {pe['median']:.1e} / {pe['p90']:.1e} | {de['median']:.3f}° / {de['p90']:.3f}° "
            f"| {dc['median']:.3f}° | {r['flat_map_deviation']['max']:.1%} / "
            f"{r['flat_map_deviation']['rms']:.2%} |"
        )
    floor = payload["source_grid_direction_floor_deg"]
    lines += [
        "",
        f"Direction floor of the 512x256 source grid itself: median {floor['median']:.3f}°. "
        f"Area ss1 output identical to bilinear: {payload['area_ss1_output_identical_to_bilinear']}.",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    args = common.parse_args(__doc__.splitlines()[0], argv)
    threads = common.set_threads(args.threads)
    meta = common.machine(threads)
    n_suns, batch, reps = (6, 3, 3) if args.quick else (64, 16, 5)
    common.log(
        f"{NAME}: {meta['device']}, torch threads {threads}, quick={args.quick}, {n_suns} suns"
    )
    rng = np.random.default_rng(args.seed)
    helper_err = check_first_moment_helper(rng)
    if helper_err > 1e-9:
        raise RuntimeError(
            f"256x256 first-moment helper disagrees with stats.first_moment ({helper_err:.2e})"
        )
    suns, dirs_world, _radii, floor = make_suns(n_suns, rng)
    rots = common.random_rotations(n_suns, rng)
    cfgs = configs()
    # With a 512x256 source and a 256x256 output the area filter's pre-downsample has nothing to do, so
    # "area ss1" may reduce to one bilinear tap per pixel; record whether it does rather than assume it.
    p0 = power(suns[:2], OMEGA_SRC)
    ss1_is_bilinear = bool(
        torch.equal(
            make_pipeline(Config(pipeline="area", supersample=1))(suns[:2], rots[:2], p0),
            make_pipeline(Config(pipeline="bilinear"))(suns[:2], rots[:2], p0),
        )
    )
    common.log("  timing")
    ms = time_per_map(cfgs, suns, rots, batch, reps)
    rows = []
    for c in cfgs:
        common.log(f"  accuracy: {c.name}")
        rows.append(
            {
                "name": c.name,
                "label": c.label,
                **asdict(c),
                "ms_per_map": common.Spread.of(ms[c.name]).to_dict(),
                **evaluate(c, suns, rots, dirs_world, batch),
            }
        )
    payload = {
        "benchmark": NAME,
        "quick": args.quick,
        "config": {
            "source": f"disc sun on black, {2 * SRC_HEIGHT}x{SRC_HEIGHT} Blender-convention map "
            "(gaffer_envmap.testing.disc_sun_map, 4x4 edge coverage)",
            "output": f"{OUT}x{OUT} camera-frame map (neural-gaffer-camera layout)",
            "suns": n_suns,
            "radius_deg": list(RADIUS_DEG),
            "sun_radiance": SUN_RADIANCE,
            "sun_directions": "uniform on the sphere",
            "rotations": "uniform random (Haar)",
            "timing_batch": batch,
            "timing_repetitions": reps,
            "seed": args.seed,
            "renormalize_note": "area: rotate_to_camera(renormalize=True); others: same global rescale "
            "applied by the benchmark",
        },
        "machine": meta,
        "area_ss1_output_identical_to_bilinear": ss1_is_bilinear,
        "source_grid_direction_floor_deg": summary(floor),
        "first_moment_helper_check_rel_err": helper_err,
        "results": rows,
    }
    fig = plot(rows, meta, args.quick, float(np.median(floor)))
    written = common.write_results(NAME, payload, fig, args.update_baseline)
    if args.update_baseline:
        common.update_readme(NAME, readme_table(payload))
    baseline = common.load_baseline(NAME)
    base = {r["name"]: r["ms_per_map"]["median"] for r in baseline["results"]} if baseline else {}
    print(
        f"\n{NAME} on {meta['device']} (torch {meta['torch']}, {threads} threads, {meta['cuda']} cuda)"
    )
    print(
        f"{'pipeline':28s} {'ms/map':>8s} {'base ms':>8s} {'power err med':>14s} {'p90':>9s} "
        f"{'dir err med':>12s} {'p90':>7s} {'centroid med':>13s}"
    )
    for r in rows:
        b = base.get(r["name"])
        print(
            f"{r['name']:28s} {r['ms_per_map']['median']:8.2f} {(f'{b:8.2f}' if b else '-'):>8s} "
            f"{r['power_error']['median']:14.2e} {r['power_error']['p90']:9.2e} "
            f"{r['direction_error_deg_first_moment']['median']:12.4f} "
            f"{r['direction_error_deg_first_moment']['p90']:7.4f} "
            f"{r['direction_error_deg_bright_centroid']['median']:13.4f}"
        )
    print(f"source-grid direction floor (deg): {payload['source_grid_direction_floor_deg']}")
    print(f"area ss1 output identical to bilinear: {ss1_is_bilinear}")
    for path in written:
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
