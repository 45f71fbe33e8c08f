"""The Blender worker: renders one object's plan into its folder. Run as a subprocess only:

    python -m gaffer_data.render.worker --job OBJECT_DIR/_plan.json [--threads N]

It imports bpy and the numpy-only modules of gaffer-envmap (`augment`, `atomic`, `sanitize`), never pymeshlab or
torch (a test checks `sys.modules`), writes every image atomically and skips images that already
exist (so a killed object resumes where it stopped), and reports progress on stdout as lines starting
with `GAFFER_EVENT ` followed by JSON. Exit codes: 0 done, 2 bad input, 3 bpy missing, 1 other errors.
"""

# pyright: reportAttributeAccessIssue=false, reportMissingImports=false
# (bpy and mathutils are C extension modules without type stubs: their attributes are made at run
# time by Blender's RNA, so pyright cannot see them. Everything else here is checked.)

import argparse
import ctypes
import json
import logging
import os
import signal
import sys
import time
from collections import OrderedDict
from pathlib import Path
from typing import Any

import numpy as np

from gaffer_data._atomic import atomic_write, atomic_write_json
from gaffer_data.dataset.manifest import plan_from_json, read_json
from gaffer_data.dataset.schema import EnvmapRef, ObjectPlan, ViewRecord
from gaffer_data.errors import GafferDataError, InputError
from gaffer_data.render._metadata import strip_volatile_metadata
from gaffer_data.render.plan import look_at_c2w_blender
from gaffer_envmap.augment import AugmentSpec
from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.errors import GafferEnvmapError

logger = logging.getLogger("gaffer_data.render.worker")

EVENT_PREFIX = "GAFFER_EVENT "
NORMALIZATION_NAME = "_normalization.json"
_IMAGE_CACHE_SIZE = 6


def emit(event: str, **fields: Any) -> None:
    """Write one progress event line to stdout (the parent parses these)."""
    sys.stdout.write(EVENT_PREFIX + json.dumps({"event": event, **fields}) + "\n")
    sys.stdout.flush()


def _die_with_parent() -> None:
    # Linux: get SIGKILL when the parent dies, so a killed run leaves no orphan writing into the folder.
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except OSError:
        return
    if os.getppid() == 1:
        os._exit(1)


def augment_envmap_pixels(pixels: np.ndarray, ref: EnvmapRef) -> np.ndarray:
    """Apply `ref`'s augmentation to lat-long pixels with gaffer-envmap's `AugmentSpec`.

    Args:
        pixels: `[He, We, 3|4]` top-down float pixels (Blender convention); alpha is dropped.
        ref: the draw (flip, then a yaw roll of `yaw_step / num_steps` of a turn).

    Returns:
        `[He, We, 4]` float32 RGBA pixels with alpha 1, ready for `_scene.image_from_pixels`.

    Raises:
        InputError: the map is not 2:1 or its width is not divisible by `num_steps`.
    """
    try:
        env = EnvironmentMap(radiance_linear=np.asarray(pixels)[..., :3])
        spec = AugmentSpec(flip=ref.flip, yaw_step=ref.yaw_step, num_steps=ref.num_steps)
        rgb = spec.apply(env).radiance_linear
    except GafferEnvmapError as exc:
        raise InputError(
            f"environment map `{ref.source}` cannot be augmented ({exc}); use 2:1 lat-long maps whose "
            "width `augment.yaw_steps` divides."
        ) from exc
    return np.concatenate([rgb, np.ones_like(rgb[..., :1])], axis=-1)


def sanitize_envmap_pixels(pixels: np.ndarray, policy: str, source: str) -> np.ndarray:
    """`pixels` as Blender loaded them, with `policy` (`RenderConfig.envmap_sanitize`) applied to RGB.

    The parent checked every map with gaffer-envmap's `read_envmap(source, sanitize=policy)` before
    the run (`check_pool_pixels`); this applies the same policy to the same pixels, so the renderer
    sees what `read_envmap` gives (under "raise": the tiny negatives of lossy compression set to 0).

    Raises:
        InputError: the policy refuses the map (it changed since the parent's check).
    """
    from typing import cast

    from gaffer_envmap.errors import NonFiniteError
    from gaffer_envmap.sanitize import SanitizePolicy, sanitize

    pixels = np.asarray(pixels)
    try:
        # the render config holds the policy as a str, checked against SANITIZE_POLICIES when made
        rgb, _ = sanitize(pixels[..., :3], cast(SanitizePolicy, policy), name=source)
    except NonFiniteError as exc:
        raise InputError(f"environment map {exc}") from exc
    if np.may_share_memory(rgb, pixels):  # clean: `sanitize` returned the pixels themselves
        return pixels
    return np.concatenate([rgb, pixels[..., 3:]], axis=-1)


class _EnvmapCache:
    """Augmented world images, loaded once per (source, flip, yaw) and evicted least recently used."""

    def __init__(self, sanitize: str = "raise") -> None:
        self._sanitize = sanitize
        self._sources: OrderedDict[str, np.ndarray] = OrderedDict()
        self._images: OrderedDict[tuple[str, bool, int, int], Any] = OrderedDict()

    def get(self, ref: EnvmapRef) -> Any:
        from gaffer_data.render import _scene

        key = (ref.source, ref.flip, ref.yaw_step, ref.num_steps)
        if key in self._images:
            self._images.move_to_end(key)
            return self._images[key]
        if ref.source not in self._sources:
            path = Path(ref.source)
            if not path.is_file():
                raise InputError(
                    f"environment map `{path}` is missing; restore the `--envmaps` folder."
                )
            self._sources[ref.source] = sanitize_envmap_pixels(
                _scene.load_envmap_pixels(path), self._sanitize, ref.source
            )
            while len(self._sources) > 2:
                self._sources.popitem(last=False)
        pixels = augment_envmap_pixels(self._sources[ref.source], ref)
        image = _scene.image_from_pixels(f"env_{ref.name}_{int(ref.flip)}_{ref.yaw_step}", pixels)
        self._images[key] = image
        while len(self._images) > _IMAGE_CACHE_SIZE:
            import bpy

            _, old = self._images.popitem(last=False)
            bpy.data.images.remove(old)
        return image


def _save_render(scene: Any, path: Path, fmt: str) -> None:
    """Save the current Render Result as float32 RGBA EXR or 8-bit RGBA PNG, atomically.

    The file holds no date or timing metadata (stamps are off, Cycles' timings are stripped), so the
    same plan always gives the same bytes.
    """
    import bpy

    settings = scene.render.image_settings
    settings.media_type = "IMAGE"
    if fmt == "EXR":
        settings.file_format = "OPEN_EXR"
        settings.color_depth = "32"
        settings.exr_codec = "ZIP"
    else:
        settings.file_format = "PNG"
        settings.color_depth = "8"
        settings.compression = 15
    settings.color_mode = "RGBA"
    result = bpy.data.images["Render Result"]

    def write(tmp: Path) -> None:
        result.save_render(str(tmp), scene=scene)
        strip_volatile_metadata(
            tmp
        )  # Cycles' per-render timings: the bytes must not depend on them

    atomic_write(path, write)


def _write_exr(path: Path, channels: dict[str, np.ndarray]) -> None:
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}

    def write(tmp: Path) -> None:
        with OpenEXR.File(
            header, {k: np.ascontiguousarray(v, np.float32) for k, v in channels.items()}
        ) as f:
            f.write(str(tmp))

    atomic_write(path, write)


def _write_mask(path: Path, alpha: np.ndarray) -> None:
    """The alpha as an 8-bit grey PNG, atomically (`gaffer_envmap.writers`: torch-free, one rounding)."""
    from gaffer_envmap.writers import write_png

    path.parent.mkdir(parents=True, exist_ok=True)
    write_png(path, alpha)


def _read_exr_channels(path: Path) -> dict[str, np.ndarray]:
    import OpenEXR

    out: dict[str, np.ndarray] = {}
    with OpenEXR.File(str(path), separate_channels=True) as f:
        for part in f.parts:
            for name, channel in part.channels.items():
                out[name] = np.array(channel.pixels, dtype=np.float32)
    return out


def _split_passes(multilayer: Path, root: Path, view: ViewRecord) -> None:
    """Write normal, albedo, depth (and alpha) payloads from the area render's multilayer EXR."""
    area = view.area
    if area is None:  # internal: only called for views with an area render
        raise RuntimeError(f"internal error: view {view.index} has no area render")
    ch = _read_exr_channels(multilayer)

    def pick(layer: str, names: str) -> dict[str, np.ndarray]:
        found = {}
        for c in names:
            key = next((k for k in ch if k.endswith(f"{layer}.{c}")), None)
            if key is None:
                raise GafferDataError(f"the render has no `{layer}.{c}` pass; is this bpy 5.0?")
            found[c] = ch[key]
        return found

    normal = pick("Normal", "XYZ")
    _write_exr(root / area.normal, {"R": normal["X"], "G": normal["Y"], "B": normal["Z"]})
    _write_exr(root / area.albedo, pick("Diffuse Color", "RGB"))
    _write_exr(root / area.depth, {"Z": pick("Depth", "Z")["Z"]})
    if view.alpha is not None:
        _write_mask(root / view.alpha, pick("Combined", "A")["A"])


def _done(root: Path, *paths: str | None) -> bool:
    return all(p is None or (root / p).is_file() for p in paths)


def render_plan(plan: ObjectPlan, root: Path, threads: int) -> None:
    """Render every missing image of `plan` into `root`.

    Raises:
        InputError: the source cannot be imported or has no extent.
    """
    import bpy

    from gaffer_data.render import _scene

    config = plan.config
    scene = _scene.reset_scene()
    _scene.import_object(Path(plan.source))
    scale, center = _scene.normalize_scene()
    atomic_write_json(root / NORMALIZATION_NAME, {"scale": scale, "center": list(center)})
    _scene.configure_cycles(scene, config, threads)
    camera = _scene.add_camera(scene, config)
    env_world, env_node = _scene.envmap_world(scene)
    if config.world_map_resolution > 0:
        env_world.cycles.sampling_method = "MANUAL"
        env_world.cycles.sample_map_resolution = config.world_map_resolution
    env_background = env_world.node_tree.nodes["Background"]
    env_background.inputs["Strength"].default_value = config.envmap_strength
    grey = _scene.grey_world(config.area_light.world_grey)
    light = _scene.add_area_light(scene)
    cache = _EnvmapCache(config.envmap_sanitize)
    scratch = root / ".scratch"
    for view in plan.views:
        _scene.set_camera_pose(camera, look_at_c2w_blender(view.camera.position))
        mask_pending = view.alpha is not None and not (root / view.alpha).is_file()
        for lit in view.lit:
            if _done(root, lit.exr, lit.png):
                continue
            start = time.perf_counter()
            scene.world = env_world
            env_node.image = cache.get(lit.envmap)
            env_background.inputs["Strength"].default_value = lit.envmap.strength
            light.hide_render = True
            scene.render.film_transparent = not config.background_visible
            _scene.enable_passes(scene, False)
            bpy.ops.render.render(write_still=False)
            _save_render(scene, root / lit.exr, "EXR")
            _save_render(scene, root / lit.png, "PNG")
            if mask_pending and view.area is None and view.alpha is not None:
                _write_mask(root / view.alpha, _read_exr_channels(root / lit.exr)["A"])
                mask_pending = False
            emit("image", path=lit.exr, seconds=time.perf_counter() - start)
        area = view.area
        if area is None or _done(
            root, area.exr, area.png, area.normal, area.albedo, area.depth, view.alpha
        ):
            continue
        start = time.perf_counter()
        scene.world = grey
        light.hide_render = False
        light.location = area.light.location
        light.scale = (area.light.scale,) * 3
        light.data.energy = area.light.energy
        scene.render.film_transparent = True
        _scene.enable_passes(scene, True)
        settings = scene.render.image_settings
        settings.media_type = "MULTI_LAYER_IMAGE"
        settings.file_format = "OPEN_EXR_MULTILAYER"
        settings.color_depth = "32"
        settings.exr_codec = "ZIP"
        scratch.mkdir(exist_ok=True)
        multilayer = scratch / f"area_{view.index:03d}.exr"
        scene.render.filepath = str(multilayer)
        bpy.ops.render.render(write_still=True)
        _split_passes(multilayer, root, view)
        _save_render(scene, root / area.exr, "EXR")
        _save_render(scene, root / area.png, "PNG")
        multilayer.unlink(missing_ok=True)
        emit("image", path=area.exr, seconds=time.perf_counter() - start)
    if scratch.is_dir():
        for leftover in scratch.iterdir():
            leftover.unlink()
        scratch.rmdir()


def main(argv: list[str] | None = None) -> int:
    """Entry point of `python -m gaffer_data.render.worker`."""
    parser = argparse.ArgumentParser(prog="python -m gaffer_data.render.worker")
    parser.add_argument("--job", required=True, type=Path, help="the object's _plan.json")
    parser.add_argument("--threads", type=int, default=0, help="Cycles threads (0: all cores)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr, format="%(name)s: %(message)s")
    _die_with_parent()
    try:
        import bpy  # noqa: F401
    except ImportError:
        sys.stderr.write('bpy is not installed; pip install "gaffer-data[render]"\n')
        return 3
    try:
        plan = plan_from_json(read_json(args.job))
        render_plan(plan, args.job.parent, args.threads)
    except InputError as exc:
        emit("error", kind="input", message=str(exc))
        return 2
    except (
        Exception
    ) as exc:  # the parent records the reason and retries; never a traceback-less death
        logger.exception("rendering failed")
        emit("error", kind=type(exc).__name__, message=str(exc))
        return 1
    emit("done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
