"""Which objects a run trains on: the objects of a dataset folder, the deterministic train / validation
split, and the check that a run does not mix two lighting encodings."""

import hashlib
from collections.abc import Sequence
from pathlib import Path

from gaffer_data import GafferDataError, open_authors_dataset, open_dataset
from gaffer_data.dataset import dataset_kind
from gaffer_diffusion.errors import ConfigError
from gaffer_diffusion.training.config import LightingCompat
from gaffer_diffusion.training.errors import DataError


def split_object_ids(
    object_ids: Sequence[str], num_val: int, *, salt: str = "gaffer-val"
) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Deterministic (train, val) split: the `num_val` ids with the smallest sha256(salt + id).

    Independent of the order and of ids added later (an object never moves from train to val).

    Raises:
        ConfigError: when `num_val` (`data.val_objects`) is not below the number of objects: holding
            them all out would leave nothing to train on (it used to be cut silently to
            `len(object_ids) - 1`, so `val_objects: 50` on 12 objects trained on 1).
    """
    if num_val > 0 and num_val >= len(object_ids):
        n = len(object_ids)
        fix = (
            f"pass `data.val_objects` of at most {n - 1} (e.g. {max(1, n // 10)})"
            if n > 1
            else "render more objects (at least 2)"
        )
        raise ConfigError(
            f"`data.val_objects` is {num_val}, but the dataset (`data.root`) holds {n} object(s): "
            f"holding out {num_val} would leave none to train on. {fix.capitalize()}, set it to 0 "
            "(no validation), or hold out a separate `data.val_root`."
        )
    ranked = sorted(object_ids, key=lambda i: hashlib.sha256(f"{salt}:{i}".encode()).hexdigest())
    val = set(ranked[:num_val])
    return (
        tuple(i for i in sorted(object_ids) if i not in val),
        tuple(i for i in sorted(object_ids) if i in val),
    )


def dataset_object_ids(root: str | Path) -> tuple[str, ...]:
    """The complete objects of a render folder or of a converted authors' split, sorted.

    Raises:
        DataError: `root` is not a dataset folder (naming the argument and the fix).
    """
    try:
        if dataset_kind(root) == "authors":
            return tuple(open_authors_dataset(root).object_ids)
        return tuple(open_dataset(root).object_ids)
    except (GafferDataError, OSError, ValueError) as exc:
        raise DataError(
            f"`data.root` / `data.val_root` {str(root)!r} is not a readable dataset ({exc}). Pass a "
            "`gaffer-data render` output folder or the `--out` folder of `gaffer-data "
            "convert-authors`."
        ) from exc


def check_lighting_compat(roots: Sequence[str | Path], compat: LightingCompat) -> None:
    """Refuse a run that would mix the authors' encoded maps with another lighting encoding.

    The authors' maps (converted splits) are the "neural-gaffer" encoding; environment maps of render
    folders are encoded with `compat`. Both in one run (training or validation) need
    `compat == "neural-gaffer"`, or the model sees two different conditionings for the same light.

    Raises:
        DataError: renders and authors' splits together with `compat="default"`.
    """
    kinds = {str(r): dataset_kind(r) for r in roots}
    authors = [r for r, k in kinds.items() if k == "authors"]
    renders = [r for r, k in kinds.items() if k == "render"]
    if authors and renders and compat != "neural-gaffer":
        raise DataError(
            f"The converted authors' split(s) {authors} come with the authors' 'neural-gaffer' "
            f"lighting encoding, but the render folder(s) {renders} would be encoded with "
            f"`data.lighting_compat` = {compat!r}. Set `data.lighting_compat` to 'neural-gaffer' to "
            "mix them, or train and validate on one kind of dataset."
        )
