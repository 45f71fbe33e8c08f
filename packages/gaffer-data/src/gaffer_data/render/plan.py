"""Pure planning of an object's render (no bpy): cameras, envmap draws, area lights, output paths.

Determinism: every random number of an object comes from `SeedSequence([seed, hash(object_id)])`, split
into independent streams for cameras, envmap draws and area lights. The plan therefore depends only on
(config, seed, object id, pool), not on the order, sharding or worker count of a run, and changing e.g.
the number of lightings leaves the cameras unchanged.
"""

import hashlib
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gaffer_data.config import MultiviewConfig, RenderConfig
from gaffer_data.dataset.schema import (
    AreaLightImage,
    AreaLightSample,
    CameraPoses,
    CameraSample,
    EnvmapRef,
    Intrinsics,
    LitImage,
    ObjectPlan,
    ViewRecord,
)
from gaffer_data.errors import ConfigError, InputError
from gaffer_envmap.poses import look_at_w2c_blender

ENVMAP_SUFFIXES = (".exr", ".hdr")
# Blender camera axes (x right, y up, looking down -z) -> OpenCV axes (x right, y down, looking down +z).
_BLENDER_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True, kw_only=True)
class PoolEntry:
    """One environment map of the lighting pool."""

    name: str
    path: Path
    sha256: str


def stable_object_hash(object_id: str) -> int:
    """A 64-bit integer from the object id, stable across processes and Python versions."""
    return int.from_bytes(hashlib.sha256(object_id.encode("utf-8")).digest()[:8], "little")


def camera_position(elevation_deg: float, azimuth_deg: float, distance: float) -> np.ndarray:
    """`[3]` position on the sphere: distance * (cos e cos a, cos e sin a, sin e), Blender world (z up)."""
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    return distance * np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])


def look_at_c2w_blender(
    position: Sequence[float], target: Sequence[float] = (0.0, 0.0, 0.0)
) -> np.ndarray:
    """`[4, 4]` camera-to-world of a Blender camera at `position` looking at `target` with +z up.

    The rotation is gaffer-envmap's `look_at_w2c_blender` (Blender cameras look down their local -z
    with local +y up, as a Track To constraint (-Z, up Y) sets them; straight above or below the target
    +y is used as up), transposed; the translation is `position` itself, not `-R^T t`, so the matrix is
    bit-identical to the formula this package used before.

    Raises:
        gaffer_envmap.errors.PoseError: `position` equals `target`.
    """
    pos = np.asarray(position, dtype=np.float64)
    tx, ty, tz = (float(c) for c in target)
    w2c = look_at_w2c_blender(pos, target=(tx, ty, tz))
    c2w = np.eye(4)
    c2w[:3, :3], c2w[:3, 3] = w2c.rotation.T, pos
    return c2w


def poses_from_c2w_blender(c2w_blender: np.ndarray, intrinsics: Intrinsics) -> CameraPoses:
    """Stack per-view matrices into the `cameras.npz` payload.

    Args:
        c2w_blender: `[V, 4, 4]` camera-to-world matrices in Blender camera axes.
        intrinsics: the shared intrinsics.
    """
    c2w_blender = np.asarray(c2w_blender, dtype=np.float64)
    w2c = np.linalg.inv(c2w_blender)[:, :3, :]  # [V, 3, 4]
    c2w_cv = c2w_blender @ _BLENDER_TO_OPENCV  # [V, 4, 4]  flips the camera's y and z axes
    return CameraPoses(w2c_blender=w2c, c2w_opencv=c2w_cv, intrinsics=intrinsics.matrix())


def intrinsics_for(config: RenderConfig) -> Intrinsics:
    """Pixel intrinsics of the square render (Blender's sensor fit AUTO = width for square images)."""
    f = config.camera.lens_mm / config.camera.sensor_mm * config.resolution
    c = config.resolution / 2.0
    return Intrinsics(width=config.resolution, height=config.resolution, fx=f, fy=f, cx=c, cy=c)


def scan_envmaps(folder: str | Path) -> tuple[PoolEntry, ...]:
    """The lighting pool: every `.exr`/`.hdr` file directly in `folder`, sorted by name.

    Raises:
        InputError: the folder does not exist or holds no environment map.
    """
    from gaffer_data.dataset.manifest import sha256_file

    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(
            f"`envmaps`={str(folder)!r} is not a folder; pass a folder of .exr/.hdr maps."
        )
    files = sorted(
        p for p in folder.iterdir() if p.suffix.lower() in ENVMAP_SUFFIXES and p.is_file()
    )
    if not files:
        raise InputError(
            f"`envmaps`={str(folder)!r} holds no .exr or .hdr file; add environment maps "
            "(e.g. `gaffer-data recipe` writes the bundled CC0 ones)."
        )
    names = [p.stem for p in files]
    if len(set(names)) != len(names):
        raise InputError(f"`envmaps`={str(folder)!r} has two maps with the same stem; rename one.")
    return tuple(PoolEntry(name=p.stem, path=p.resolve(), sha256=sha256_file(p)) for p in files)


_EXR_MAGIC = b"\x76\x2f\x31\x01"
_HEADER_BYTES = 1 << 16
"""The first 64 KiB hold the (first part's) header of any EXR or Radiance file the pool may hold."""


def envmap_size(path: str | Path) -> tuple[int, int]:
    """`(width, height)` of an `.exr` / `.hdr` file from its header alone (no pixels decoded).

    EXR: the first part's `dataWindow` attribute; Radiance: the resolution line (`-Y H +X W`).

    Raises:
        InputError: the file cannot be read or its header is not an EXR / Radiance header.
    """
    path = Path(path)
    try:
        with path.open("rb") as fh:
            head = fh.read(_HEADER_BYTES)
    except OSError as exc:
        raise InputError(f"environment map `{path}` cannot be read ({exc}).") from exc
    size = _exr_size(head) if head.startswith(_EXR_MAGIC) else _radiance_size(head)
    if size is None or min(size) < 1:
        raise InputError(
            f"environment map `{path}` has no readable EXR or Radiance header; re-export it as a "
            "lat-long .exr or .hdr, or remove it from `--envmaps`."
        )
    return size


def _exr_size(head: bytes) -> tuple[int, int] | None:
    pos = 8  # magic + version/flags; then (name\0 type\0 int32 size value)* up to an empty name
    while pos < len(head) and head[pos] != 0:
        name_end = head.find(b"\0", pos)
        type_end = head.find(b"\0", name_end + 1)
        if name_end < 0 or type_end < 0 or type_end + 5 > len(head):
            return None
        n = int.from_bytes(head[type_end + 1 : type_end + 5], "little", signed=True)
        value = head[type_end + 5 : type_end + 5 + n]
        if head[pos:name_end] == b"dataWindow" and head[name_end + 1 : type_end] == b"box2i":
            if len(value) != 16:
                return None
            x0, y0, x1, y1 = np.frombuffer(value, dtype="<i4").tolist()
            return x1 - x0 + 1, y1 - y0 + 1
        if n < 0:
            return None
        pos = type_end + 5 + n
    return None


def _radiance_size(head: bytes) -> tuple[int, int] | None:
    if not head.startswith((b"#?RADIANCE", b"#?RGBE")):
        return None
    end = head.find(b"\n\n")
    if end < 0:
        return None
    line = head[end + 2 :].split(b"\n", 1)[0].split()
    if len(line) != 4 or {line[0][1:], line[2][1:]} != {b"X", b"Y"}:
        return None
    try:
        dims = {line[0][1:]: int(line[1]), line[2][1:]: int(line[3])}
    except ValueError:
        return None
    return dims[b"X"], dims[b"Y"]


def check_pool_maps(pool: Sequence[PoolEntry], yaw_steps: int) -> None:
    """Refuse, before anything is rendered, maps that are not 2:1 or that `yaw_steps` cannot divide.

    Every lighting is a lat-long map rolled by whole `width / yaw_steps` columns (gaffer-envmap's
    `AugmentSpec`), so both would otherwise fail per object, late, in the Blender workers.

    Raises:
        InputError: a map is not 2:1 (names the file, its size and the fix), or its header is bad.
        ConfigError: `yaw_steps` does not divide a map's width (names the divisors that would).
    """
    sizes = {entry.path: envmap_size(entry.path) for entry in pool}
    for path, (w, h) in sizes.items():
        if w != 2 * h:
            ratio = f"{w / h:.3g}:1"
            raise InputError(
                f"`--envmaps` map `{path.name}` is {w} x {h} ({ratio}), not a 2:1 lat-long map; "
                f"resample it to {2 * h} x {h} (or {w} x {w // 2}) or remove it from the folder."
            )
    bad = [(p, w) for p, (w, _) in sizes.items() if w % yaw_steps]
    if bad:
        common = math.gcd(*(w for w, _ in sizes.values()))
        divisors = [d for d in range(1, 65) if common % d == 0]
        path, w = bad[0]
        more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
        raise ConfigError(
            f"`--yaw-steps` (`augment.yaw_steps`) is {yaw_steps}, which does not divide the width {w} of "
            f"`{path.name}`{more}: the yaw roll must move whole pixel columns; pass one of "
            f"{divisors} (1: no yaw)."
        )


def check_pool_pixels(pool: Sequence[PoolEntry], policy: str = "raise") -> int:
    """Read every map of the pool with gaffer-envmap and `policy` (`RenderConfig.envmap_sanitize`),
    before anything is rendered: a map the policy refuses (NaN, Inf, a substantial negative under
    "raise"; any of them under "strict") stops the run here, not per object in the workers.

    The workers apply the same policy to the pixels Blender loads (`gaffer_data.render.worker`), so
    what is rendered is what gaffer-envmap's `read_envmap(source, sanitize=policy)` gives; under
    "raise" the tiny negatives of lossy compression are set to 0 with an INFO line.

    Returns:
        How many maps the policy changes (0: every map is clean, the policy makes no difference).

    Raises:
        InputError: a map the policy refuses (names the file, the counts and `--sanitize`).
    """
    from gaffer_envmap.errors import NonFiniteError
    from gaffer_envmap.io import read_envmap
    from gaffer_envmap.sanitize import sanitize_flag_refusal

    changed = 0
    for entry in pool:
        try:
            env = read_envmap(entry.path, sanitize=policy)  # type: ignore[arg-type]
        except NonFiniteError as exc:
            raise InputError(
                f"`--envmaps` map {sanitize_flag_refusal(exc, policy)} Nothing was rendered."
            ) from exc
        changed += bool(env.metadata and "sanitize" in env.metadata)
    return changed


def _uniform(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return float(rng.uniform(bounds[0], bounds[1]))


def plan_object(
    object_id: str, source: str | Path, pool: Sequence[PoolEntry], config: RenderConfig
) -> ObjectPlan:
    """Sample the cameras, envmap draws and area lights of one object and name its outputs.

    Args:
        object_id: the object's id (also seeds its random streams).
        source: the mesh file.
        pool: the lighting pool (`scan_envmaps`); may be empty only when `config.lightings == 0`.
        config: the render config.

    Returns:
        The object's plan.

    Raises:
        InputError: an empty pool with `config.lightings > 0`.
    """
    if config.lightings > 0 and not pool:
        raise InputError("`pool` is empty but `lightings` > 0; pass a folder of environment maps.")
    seq = np.random.SeedSequence([config.seed, stable_object_hash(object_id)])
    cam_rng, env_rng, area_rng = (np.random.default_rng(s) for s in seq.spawn(3))
    cam_cfg, area_cfg, aug = config.camera, config.area_light, config.augment
    views = []
    for v in range(config.views):
        elevation = _uniform(cam_rng, cam_cfg.elevation_deg)
        azimuth = _uniform(cam_rng, cam_cfg.azimuth_deg)
        distance = _uniform(cam_rng, cam_cfg.distance)
        x, y, z = (float(c) for c in camera_position(elevation, azimuth, distance))
        camera = CameraSample(
            elevation_deg=elevation, azimuth_deg=azimuth, distance=distance, position=(x, y, z)
        )
        lit = []
        for li in range(config.lightings):
            entry = pool[int(env_rng.integers(len(pool)))]
            flip = bool(env_rng.integers(2)) if aug.flip else False
            yaw_step = int(env_rng.integers(aug.yaw_steps))
            ref = EnvmapRef(
                name=entry.name,
                source=str(entry.path),
                source_sha256=entry.sha256,
                flip=flip,
                yaw_step=yaw_step,
                num_steps=aug.yaw_steps,
                strength=config.envmap_strength,
            )
            lit.append(
                LitImage(
                    lighting_index=li,
                    envmap=ref,
                    exr=f"lit/{v:03d}_{li:03d}.exr",
                    png=f"lit/{v:03d}_{li:03d}.png",
                )
            )
        area = None
        if config.area_light_render:
            light = AreaLightSample(
                location=(
                    _uniform(area_rng, area_cfg.xy),
                    _uniform(area_rng, area_cfg.xy),
                    _uniform(area_rng, area_cfg.z),
                ),
                energy=_uniform(area_rng, area_cfg.energy),
                scale=area_cfg.scale,
                world_grey=area_cfg.world_grey,
            )
            area = AreaLightImage(
                light=light,
                exr=f"area/{v:03d}.exr",
                png=f"area/{v:03d}.png",
                normal=f"normal/{v:03d}.exr",
                albedo=f"albedo/{v:03d}.exr",
                depth=f"depth/{v:03d}.exr",
            )
        has_mask = area is not None or (lit and not config.background_visible)
        views.append(
            ViewRecord(
                index=v,
                camera=camera,
                lit=tuple(lit),
                area=area,
                alpha=f"alpha/{v:03d}.png" if has_mask else None,
            )
        )
    return ObjectPlan(
        object_id=object_id,
        source=str(source),
        views=tuple(views),
        intrinsics=intrinsics_for(config),
        config=config,
    )


def plan_poses(plan: ObjectPlan) -> CameraPoses:
    """The `cameras.npz` payload of a plan (cameras look at the origin, +z up)."""
    c2w = np.stack([look_at_c2w_blender(v.camera.position) for v in plan.views])
    return poses_from_c2w_blender(c2w, plan.intrinsics)


def multiview_positions(multiview: MultiviewConfig, rng: np.random.Generator) -> np.ndarray:
    """`[N, 3]` (elevation_deg, azimuth_deg, distance) of the layout's N = train + test cameras.

    "sphere": a Fibonacci lattice, uniform in solid angle over the elevation band (z uniform in
    [sin e0, sin e1], azimuth stepping by the golden angle), turned about z by a random offset;
    "orbit": one ring at `orbit_elevation_deg` with evenly spaced azimuths from a random offset.
    """
    n = multiview.views
    offset = float(rng.uniform(0.0, 360.0))
    i = np.arange(n) + 0.5
    if multiview.layout == "sphere":
        lo, hi = np.sin(np.deg2rad(multiview.elevation_deg))
        elevation = np.rad2deg(np.arcsin(lo + (hi - lo) * i / n))
        golden_deg = 180.0 * (3.0 - np.sqrt(5.0))
        azimuth = np.mod(offset + golden_deg * np.arange(n), 360.0)
    else:
        elevation = np.full(n, multiview.orbit_elevation_deg)
        azimuth = np.mod(offset + 360.0 * np.arange(n) / n, 360.0)
    return np.stack([elevation, azimuth, np.full(n, multiview.distance)], axis=-1)


def plan_multiview_object(
    object_id: str, source: str | Path, pool: Sequence[PoolEntry], config: RenderConfig
) -> ObjectPlan:
    """Plan a multi-view set: fixed layout, train/test splits, the same lightings for every view.

    Views `0 .. train_views - 1` are the training split (in layout order), the rest the test split; a
    seeded permutation picks which layout points are held out. The `config.lightings` draws are made
    once per object (distinct pool maps while the pool allows), each with its flip and yaw.

    Raises:
        ConfigError: `config.multiview` is None.
        InputError: an empty pool with `config.lightings > 0`.
    """
    multiview = config.multiview
    if multiview is None:
        raise ConfigError("`config.multiview` is None; use `plan_object` for relighting datasets.")
    if config.lightings > 0 and not pool:
        raise InputError("`pool` is empty but `lightings` > 0; pass a folder of environment maps.")
    seq = np.random.SeedSequence([config.seed, stable_object_hash(object_id)])
    cam_rng, env_rng, area_rng = (np.random.default_rng(s) for s in seq.spawn(3))
    positions = multiview_positions(multiview, cam_rng)
    held_out = np.sort(cam_rng.permutation(multiview.views)[: multiview.test_views])
    order = [k for k in range(multiview.views) if k not in set(held_out.tolist())]
    order += held_out.tolist()
    replace = config.lightings > len(pool)
    picks = env_rng.choice(len(pool), size=config.lightings, replace=replace) if pool else []
    refs = []
    for index in picks:
        entry = pool[int(index)]
        flip = bool(env_rng.integers(2)) if config.augment.flip else False
        refs.append(
            EnvmapRef(
                name=entry.name,
                source=str(entry.path),
                source_sha256=entry.sha256,
                flip=flip,
                yaw_step=int(env_rng.integers(config.augment.yaw_steps)),
                num_steps=config.augment.yaw_steps,
                strength=config.envmap_strength,
            )
        )
    area_cfg = config.area_light
    views = []
    for v, k in enumerate(order):
        elevation, azimuth, distance = (float(x) for x in positions[k])
        x, y, z = (float(c) for c in camera_position(elevation, azimuth, distance))
        lit = tuple(
            LitImage(
                lighting_index=li,
                envmap=ref,
                exr=f"lit/{v:03d}_{li:03d}.exr",
                png=f"lit/{v:03d}_{li:03d}.png",
            )
            for li, ref in enumerate(refs)
        )
        area = None
        if config.area_light_render:
            area = AreaLightImage(
                light=AreaLightSample(
                    location=(
                        _uniform(area_rng, area_cfg.xy),
                        _uniform(area_rng, area_cfg.xy),
                        _uniform(area_rng, area_cfg.z),
                    ),
                    energy=_uniform(area_rng, area_cfg.energy),
                    scale=area_cfg.scale,
                    world_grey=area_cfg.world_grey,
                ),
                exr=f"area/{v:03d}.exr",
                png=f"area/{v:03d}.png",
                normal=f"normal/{v:03d}.exr",
                albedo=f"albedo/{v:03d}.exr",
                depth=f"depth/{v:03d}.exr",
            )
        has_mask = area is not None or (lit and not config.background_visible)
        views.append(
            ViewRecord(
                index=v,
                camera=CameraSample(
                    elevation_deg=elevation,
                    azimuth_deg=azimuth,
                    distance=distance,
                    position=(x, y, z),
                ),
                lit=lit,
                area=area,
                alpha=f"alpha/{v:03d}.png" if has_mask else None,
                split="train" if v < multiview.train_views else "test",
            )
        )
    return ObjectPlan(
        object_id=object_id,
        source=str(source),
        views=tuple(views),
        intrinsics=intrinsics_for(config),
        config=config,
    )


def plan_for(
    object_id: str, source: str | Path, pool: Sequence[PoolEntry], config: RenderConfig
) -> ObjectPlan:
    """`plan_multiview_object` when `config.multiview` is set, else `plan_object`."""
    if config.multiview is not None:
        return plan_multiview_object(object_id, source, pool, config)
    return plan_object(object_id, source, pool, config)


def camera_angle_x(config: RenderConfig) -> float:
    """Horizontal field of view in radians (NeRF-Synthetic's `camera_angle_x`): 2 atan(sensor / 2 lens)."""
    return 2.0 * math.atan(config.camera.sensor_mm / (2.0 * config.camera.lens_mm))


def nerf_transforms(plan: ObjectPlan, split: str) -> dict[str, object]:
    """The NeRF-Synthetic `transforms_{split}.json` body of a multi-view plan.

    `transform_matrix` is the 4x4 camera-to-world in Blender's world (z up) and Blender/OpenGL camera
    axes (x right, y up, the camera looks along -z): exactly what NeRF-Synthetic stores, so loaders
    written for it (which flip y and z to get OpenCV) work unchanged. `file_path` is the lighting-0 PNG
    without its suffix, relative to the object folder (loaders append ".png"); the PNG has straight
    alpha over a transparent film, as NeRF-Synthetic's. Each frame also lists every lighting's image
    (`lit`), and the top level the lightings, the intrinsics in pixels and the convention by name.

    Raises:
        ConfigError: `split` is not "train" or "test", or the plan is not a multi-view plan.
    """
    if split not in ("train", "test"):
        raise ConfigError(f"`split`={split!r} must be 'train' or 'test'.")
    if plan.config.multiview is None:
        raise ConfigError("`plan` is not a multi-view plan (`config.multiview` is None).")
    poses = plan_poses(plan)
    lightings = []
    if plan.views and plan.views[0].lit:
        lightings = [
            {
                "lighting_index": li.lighting_index,
                "envmap": li.envmap.name,
                "flip": li.envmap.flip,
                "yaw_step": li.envmap.yaw_step,
                "num_steps": li.envmap.num_steps,
            }
            for li in plan.views[0].lit
        ]
    frames = []
    for view in plan.views:
        if view.split != split:
            continue
        if view.lit:
            first_png = view.lit[0].png
        elif view.area is not None:
            first_png = view.area.png
        else:  # internal: RenderConfig needs one of them
            raise RuntimeError(f"internal error: view {view.index} has no render")
        c2w = np.eye(4)
        c2w[:3] = np.linalg.inv(np.vstack([poses.w2c_blender[view.index], [0, 0, 0, 1]]))[:3]
        frames.append(
            {
                "file_path": "./" + first_png.removesuffix(".png"),
                "transform_matrix": c2w.tolist(),
                "view_index": view.index,
                "lit": [
                    {
                        "lighting_index": li.lighting_index,
                        "file_path": "./" + li.png.removesuffix(".png"),
                    }
                    for li in view.lit
                ],
                "alpha": None if view.alpha is None else "./" + view.alpha,
            }
        )
    k = plan.intrinsics
    return {
        "camera_angle_x": camera_angle_x(plan.config),
        "camera_convention": "blender_opengl_c2w",
        "w": k.width,
        "h": k.height,
        "fl_x": k.fx,
        "fl_y": k.fy,
        "cx": k.cx,
        "cy": k.cy,
        "lightings": lightings,
        "frames": frames,
    }
