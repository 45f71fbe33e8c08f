"""The (input, target lighting) pairs of a gaffer-data dataset, rendered or converted from the
authors' layout (gaffer-data is imported lazily, here only)."""

import functools
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from gaffer_diffusion.errors import ConfigError, DatasetError, MissingDependencyError
from gaffer_diffusion.evaluation.envmaps import _resolve_envmap, _verified_envmap
from gaffer_diffusion.evaluation.records import (
    DatasetKind,
    EncodedLightingFiles,
    EnvmapLighting,
    EvalPair,
    InputLighting,
)

logger = logging.getLogger(__name__)


def _require_gaffer_data() -> Any:
    try:
        import gaffer_data
    except ImportError as exc:
        raise MissingDependencyError(
            'Evaluating on a rendered dataset needs gaffer-data: pip install "gaffer-diffusion[eval]"'
        ) from exc
    return gaffer_data


def dataset_pairs(
    root: str | Path,
    *,
    input_lighting: InputLighting = 0,
    envmap_dirs: Sequence[str | Path] = (),
    limit: int | None = None,
) -> tuple[EvalPair, ...]:
    """Every (input, target lighting) pair of a gaffer-data dataset (rendered or converted).

    Args:
        root: the dataset folder: a render (`gaffer_data.open_dataset`) or a converted authors' split
            (`gaffer_data.open_authors_dataset`); the kind is read from its `dataset.json`.
        input_lighting: the lighting index of the input render of each view, or "area" for the
            area-light render (then every lighting is a target).
        envmap_dirs: folders to search for env maps whose recorded path no longer exists (renders
            only; converted datasets carry encoded maps).
        limit: keep only the first `limit` pairs (in object, view, lighting order).

    Returns:
        The pairs, in object, view, target-lighting order.

    Raises:
        MissingDependencyError: without gaffer-data.
        DatasetError: when the dataset yields no pair, a view lacks the input render, or an env map
            cannot be found.
    """
    gaffer_data = _require_gaffer_data()
    if limit is not None and limit < 1:
        raise ConfigError(f"`limit` is {limit}; expected >= 1 or None.")
    if not (input_lighting == "area" or (isinstance(input_lighting, int) and input_lighting >= 0)):
        raise ConfigError(
            f"`input_lighting` is {input_lighting!r}; expected a lighting index >= 0 or 'area'."
        )
    root = Path(root)
    if dataset_kind(root) == "authors":
        pairs = _authors_pairs(gaffer_data, root, input_lighting, limit)
    else:
        pairs = _render_pairs(gaffer_data, root, input_lighting, envmap_dirs, limit)
    if not pairs:
        raise DatasetError(
            f"`{root}` yields no (input, target) pair: it needs complete objects (with manifest.json) "
            "and at least two lightings per view (or `input_lighting='area'`)."
        )
    return tuple(pairs)


def dataset_kind(root: str | Path) -> DatasetKind:
    """ "authors" when `root/dataset.json` declares a converted authors' layout, else "render".

    Re-exported for compatibility: the test belongs to gaffer-data's format and lives in
    `gaffer_data.dataset.dataset_kind` (gaffer-data is imported here, not at module import).
    """
    from gaffer_data.dataset import dataset_kind as _kind

    return _kind(root)


def _missing_input(
    object_id: str, view: int, input_lighting: InputLighting, have: object
) -> NoReturn:
    if input_lighting == "area":
        raise DatasetError(
            f"`{object_id}` view {view} has no area-light render; pass a lighting index as "
            "`input_lighting` (`--input-lighting 0`)."
        )
    raise DatasetError(
        f"`{object_id}` view {view} has no lighting {input_lighting} (it has {have}); choose "
        "another `input_lighting`."
    )


def _authors_pairs(
    gaffer_data: Any, root: Path, input_lighting: InputLighting, limit: int | None
) -> list[EvalPair]:
    pairs: list[EvalPair] = []
    for obj in gaffer_data.open_authors_dataset(root).iter_objects():
        for view in obj.views:
            by_index = {lit.lighting_index: lit for lit in view.lit}
            if input_lighting == "area":
                if view.area_png is None:
                    _missing_input(obj.object_id, view.index, input_lighting, sorted(by_index))
                input_png, input_tag = obj.path(view.area_png), "area"
            else:
                if input_lighting not in by_index:
                    _missing_input(obj.object_id, view.index, input_lighting, sorted(by_index))
                input_png, input_tag = (
                    obj.path(by_index[input_lighting].png),
                    f"{input_lighting:03d}",
                )
            for lit in view.lit:
                if lit.lighting_index == input_lighting:
                    continue
                pairs.append(
                    EvalPair(
                        name=f"{obj.object_id}/{view.index:03d}_{input_tag}_to_{lit.lighting_index:03d}",
                        object_id=obj.object_id,
                        view_index=view.index,
                        target_lighting=lit.lighting_index,
                        input_image=input_png,
                        target_image=obj.path(lit.png),
                        mask=None,
                        lighting=EncodedLightingFiles(
                            ldr=obj.path(lit.envmap_ldr), hdr=obj.path(lit.envmap_hdr)
                        ),
                    )
                )
                if limit is not None and len(pairs) >= limit:
                    return pairs
    return pairs


def _render_pairs(
    gaffer_data: Any,
    root: Path,
    input_lighting: InputLighting,
    envmap_dirs: Sequence[str | Path],
    limit: int | None,
) -> list[EvalPair]:
    dirs = tuple(Path(d) for d in envmap_dirs)
    resolve = functools.lru_cache(maxsize=None)(
        lambda source, name, sha: _verified_envmap(
            _resolve_envmap(source, name, root, dirs), name, sha, bool(dirs)
        )
    )
    pairs: list[EvalPair] = []
    skipped_same = 0
    for obj in gaffer_data.open_dataset(root).iter_objects():
        poses = obj.poses()
        for view in obj.views:
            by_index = {lit.lighting_index: lit for lit in view.lit}
            if input_lighting == "area":
                if view.area is None:
                    _missing_input(obj.object_id, view.index, input_lighting, sorted(by_index))
                input_png, input_tag = obj.path(view.area.png), "area"
            else:
                if input_lighting not in by_index:
                    _missing_input(obj.object_id, view.index, input_lighting, sorted(by_index))
                input_png = obj.path(by_index[input_lighting].png)
                input_tag = f"{input_lighting:03d}"
            same = None if input_lighting == "area" else _lighting_key(by_index[input_lighting])
            for lit in view.lit:
                if lit.lighting_index == input_lighting:
                    continue
                if _lighting_key(lit) == same:
                    # the same map, mirror, turn and strength as the input: the render is the input
                    # itself (a duplicate draw), not a relighting task, and its PSNR is infinite
                    skipped_same += 1
                    continue
                ref = lit.envmap
                pairs.append(
                    EvalPair(
                        name=f"{obj.object_id}/{view.index:03d}_{input_tag}_to_{lit.lighting_index:03d}",
                        object_id=obj.object_id,
                        view_index=view.index,
                        target_lighting=lit.lighting_index,
                        input_image=input_png,
                        target_image=obj.path(lit.png),
                        mask=None if view.alpha is None else obj.path(view.alpha),
                        lighting=EnvmapLighting(
                            source=resolve(ref.source, ref.name, ref.source_sha256),
                            flip=bool(ref.flip),
                            yaw_step=int(ref.yaw_step),
                            num_steps=int(ref.num_steps),
                            strength=float(ref.strength),
                            w2c_blender=np.asarray(poses.w2c_blender[view.index], np.float64),
                        ),
                    )
                )
                if limit is not None and len(pairs) >= limit:
                    return _log_skipped(pairs, skipped_same)
    return _log_skipped(pairs, skipped_same)


def _lighting_key(lit: Any) -> tuple[object, ...]:
    """What decides a render's lighting: the map (by content hash), mirror, turn and strength."""
    ref = lit.envmap
    return (ref.source_sha256 or ref.name, bool(ref.flip), int(ref.yaw_step), float(ref.strength))


def _log_skipped(pairs: list[EvalPair], skipped: int) -> list[EvalPair]:
    if skipped:
        logger.info(
            "left out %d target(s) lit exactly as their input (same map, mirror, turn and strength)",
            skipped,
        )
    return pairs
