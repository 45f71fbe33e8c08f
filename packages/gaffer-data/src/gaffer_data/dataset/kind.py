"""Which of gaffer-data's two dataset layouts a folder holds, read from its `dataset.json`."""

import json
from pathlib import Path
from typing import Literal

from gaffer_data.dataset.authors import AUTHORS_DATASET_SCHEMA

DatasetKind = Literal["render", "authors"]
"""A `gaffer-data render` folder or a split converted by `gaffer-data convert-authors`."""


def dataset_kind(root: str | Path) -> DatasetKind:
    """ "authors" when `root/dataset.json` declares a converted authors' layout, else "render".

    Args:
        root: a dataset folder.

    Returns:
        "authors" for a `gaffer.authors_dataset` folder (read it with `open_authors_dataset`), else
        "render" (`open_dataset`), also when `dataset.json` is missing or malformed: the reader then
        reports the problem with its own message.
    """
    path = Path(root) / "dataset.json"
    if not path.is_file():
        return "render"
    try:
        schema = json.loads(path.read_text(encoding="utf-8")).get("schema")
    except (OSError, ValueError, AttributeError):
        return "render"  # the reader reports the malformed file with its own message
    return "authors" if schema == AUTHORS_DATASET_SCHEMA else "render"
