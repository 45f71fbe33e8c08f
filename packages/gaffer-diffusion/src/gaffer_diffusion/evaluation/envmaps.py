"""The environment maps that lit a rendered dataset: found again if moved, checked by sha256."""

from collections.abc import Sequence
from pathlib import Path

from gaffer_diffusion.errors import DatasetError
from gaffer_diffusion.evaluation.records import ENVMAP_SUFFIXES


def _resolve_envmap(
    source: str, name: str, dataset_root: Path, envmap_dirs: Sequence[Path]
) -> Path:
    """Find an env map that may have moved since rendering: as recorded, then by name in the dirs."""
    recorded = Path(source)
    candidates = [recorded]
    if not recorded.is_absolute():
        candidates.append(dataset_root / recorded)
    for d in envmap_dirs:
        candidates.append(Path(d) / recorded.name)
        candidates += [Path(d) / f"{name}{suffix}" for suffix in ENVMAP_SUFFIXES]
    for c in candidates:
        if c.is_file():
            return c
    looked = "\n".join(f"  - {c}" for c in candidates)
    raise DatasetError(
        f"The environment map `{name}` that lit this dataset was not found. Looked in:\n{looked}\n"
        "Pass the folder holding the maps the dataset was rendered with as `--envmaps DIR` "
        "(`envmap_dirs`)."
    )


def _sha256(path: Path) -> str:
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _verified_envmap(path: Path, name: str, expected: str, moved: bool) -> Path:
    """`path`, once its sha256 matches the `source_sha256` its manifest recorded: a map of
    the right name but other content would score every pair against the wrong lighting."""
    if not expected:
        return path  # an older manifest without the digest: nothing to check against
    actual = _sha256(path)
    if actual != expected.lower():
        fix = (
            "pass `--envmaps DIR` with the maps the dataset was rendered with"
            if moved
            else "restore the original map, or pass `--envmaps DIR` with the maps it was rendered with"
        )
        raise DatasetError(
            f"Environment map `{path}` is not the `{name}` this dataset was rendered with: its "
            f"sha256 is {actual[:12]}..., the manifest records {expected[:12]}...; {fix}."
        )
    return path
