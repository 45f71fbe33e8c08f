"""gaffer-data multi-view render sets (`gaffer-data render-multiview`) and their lightings.

An object folder holds `transforms_{train,test}.json` (NeRF-Synthetic format plus per-lighting images,
see `gaffer_nerf.data.transforms`) and `manifest.json`. The images and cameras are read from the
transforms files (an artifact on disk, so gaffer-data itself is optional); when gaffer-data is
installed and the folder has a manifest, its public reader (`gaffer_data.dataset.read_object`) adds
where each lighting's environment map came from, so `load_lighting_envmap` finds it without help.
"""

import importlib.util
from dataclasses import replace
from pathlib import Path

from gaffer_envmap import AugmentSpec, EnvironmentMap, read_envmap
from gaffer_envmap.sanitize import SanitizePolicy
from gaffer_nerf.data.transforms import LightingInfo, MultiViewScene, read_transforms_folder
from gaffer_nerf.errors import DatasetNotFoundError

MANIFEST_NAME = "manifest.json"


def read_gaffer_data_object(
    folder: str | Path, *, lighting_index: int = 0, downscale: int = 1, verify: bool = False
) -> MultiViewScene:
    """Read a gaffer-data multi-view object folder under one lighting.

    Args:
        folder: the object folder (`<dataset>/objects/<id>/`).
        lighting_index: which lighting's images to load (0: the one a radiance field is fitted to).
        downscale: integer image downscaling factor.
        verify: with gaffer-data installed, check every payload's sha256 against the manifest.

    Returns:
        The scene; `lightings[k].source` is set when the manifest could be read.

    Raises:
        DatasetNotFoundError, DatasetError: see `read_transforms_folder`.
    """
    folder = Path(folder)
    scene = read_transforms_folder(folder, lighting_index=lighting_index, downscale=downscale)
    if not (folder / MANIFEST_NAME).is_file() or importlib.util.find_spec("gaffer_data") is None:
        return scene
    from gaffer_data.dataset import read_object

    obj = read_object(folder, verify=verify)
    sources = {
        li.lighting_index: li.envmap.source for li in (obj.views[0].lit if obj.views else ())
    }
    lightings = tuple(
        replace(li, source=sources.get(li.lighting_index, li.source)) for li in scene.lightings
    )
    return replace(scene, lightings=lightings)


def load_lighting_envmap(
    info: LightingInfo,
    envmap_dir: str | Path | None = None,
    *,
    sanitize: SanitizePolicy = "raise",
) -> EnvironmentMap:
    """The world-frame environment map of a lighting, with its flip / yaw augmentation applied.

    Looks in `envmap_dir` for `<envmap>.exr` / `.hdr` first, then at `info.source`, then among the
    HDRIs bundled with gaffer-envmap (`gaffer_envmap.bundled_hdris`, by name), the pool gaffer-data
    renders with by default.

    Args:
        info: the lighting (env map name, source, augmentation).
        envmap_dir: a folder holding the pool's maps.
        sanitize: NaN/Inf/negative pixels (`gaffer_envmap.read_envmap`): "raise" (default; sets
            the tiny negatives of lossy compression, which 7 of the 8 bundled HDRIs hold, to 0 and
            refuses anything else), "strict", "zero" or "clamp" (CLI: `--sanitize`, same default).

    Raises:
        DatasetNotFoundError: when the map is in none of these places (the message lists them).
        gaffer_envmap.errors.NonFiniteError: bad pixels with `sanitize="raise"`.
    """
    from gaffer_envmap.bundled import bundled_hdris

    candidates: list[Path] = []
    if envmap_dir is not None:
        candidates += [Path(envmap_dir) / f"{info.envmap}{s}" for s in (".exr", ".hdr")]
    if info.source:
        candidates.append(Path(info.source))
    bundled = bundled_hdris().get(info.envmap)
    if bundled is not None:
        candidates.append(bundled)
    for path in candidates:
        if path.is_file():
            env = read_envmap(path, sanitize=sanitize)
            spec = AugmentSpec(flip=info.flip, yaw_step=info.yaw_step, num_steps=info.num_steps)
            return spec.apply(env)
    raise DatasetNotFoundError(
        f"Environment map {info.envmap!r} (lighting {info.lighting_index}) not found; looked at "
        f"{[str(p) for p in candidates] or 'nothing'}. Pass `envmap_dir` (CLI: --envmaps DIR), the "
        "folder holding the pool's .exr files."
    )
