"""Save and load a `TensoRFVM`: `field.safetensors` + `config.json` (class name, version, configs).

The grid size, box and alpha mask change during fitting, so they are stored with the weights and the
field is rebuilt at its final shape before loading (strictly).
"""

import dataclasses
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file, save_file

from gaffer_envmap.atomic import atomic_files
from gaffer_envmap.schema_header import schema_header_problem
from gaffer_nerf._version import __version__
from gaffer_nerf.configs import SceneBoxConfig, TensoRFConfig
from gaffer_nerf.errors import CheckpointError
from gaffer_nerf.fields.tensorf import TensoRFVM

CONFIG_NAME = "config.json"
WEIGHTS_NAME = "field.safetensors"
CLASS_NAME = "TensoRFVM"
FORMAT_VERSION = "1.0"


def save_field(
    field: TensoRFVM, folder: str | Path, *, extra: Mapping[str, str] | None = None
) -> Path:
    """Write `folder/config.json`, `folder/field.safetensors` and the `extra` text files (name ->
    contents, e.g. the fit's report) as one set: staged, then moved in together
    (`gaffer_envmap.atomic.atomic_files`), so a failed or killed save leaves the folder as it was,
    never new weights beside an old config. Returns the folder."""
    folder = Path(folder)
    state = {k: v.detach().cpu().contiguous() for k, v in field.state_dict().items()}
    if field.alpha_volume is not None and field.alpha_aabb is not None:
        state["alpha_volume"] = field.alpha_volume.detach().cpu().contiguous()
        state["alpha_aabb"] = field.alpha_aabb.detach().cpu().contiguous()
    with atomic_files(folder) as stage:
        _write_field(stage, field, state)
        for name, text in (extra or {}).items():
            (stage / name).write_text(text)
    return folder


def _write_field(folder: Path, field: TensoRFVM, state: dict[str, torch.Tensor]) -> None:
    save_file(state, str(folder / WEIGHTS_NAME))
    meta = {
        "_class_name": CLASS_NAME,
        "format_version": FORMAT_VERSION,
        "producer": {"package": "gaffer-nerf", "version": __version__},
        "tensorf": dataclasses.asdict(field.config),
        "scene": dataclasses.asdict(field.scene),
        "grid_size": list(field.grid_size),
    }
    (folder / CONFIG_NAME).write_text(json.dumps(meta, indent=2))


def load_field(folder: str | Path, *, device: str | torch.device = "cpu") -> TensoRFVM:
    """Load a field written by `save_field`.

    Raises:
        CheckpointError: missing files, another class, a `format_version` that is not
            "MAJOR.MINOR" or of another MAJOR than `FORMAT_VERSION`'s, or tensors that do not match.
    """
    folder = Path(folder)
    cfg_path, w_path = folder / CONFIG_NAME, folder / WEIGHTS_NAME
    if not cfg_path.is_file() or not w_path.is_file():
        raise CheckpointError(
            f"{folder} is not a gaffer-nerf checkpoint (needs {CONFIG_NAME} and {WEIGHTS_NAME}); "
            "make one with `gaffer-nerf fit`."
        )
    meta = json.loads(cfg_path.read_text())
    # the shared header check (gaffer_envmap.schema_header) on this file's own keys: `_class_name`
    # plays `schema`, `format_version` `schema_version`; a newer MINOR is read
    header = {
        "schema": meta.get("_class_name"),
        "schema_version": str(meta.get("format_version", "0")),
    }
    problem = schema_header_problem(header, schema=CLASS_NAME, version=FORMAT_VERSION)
    if problem == "foreign_schema":
        raise CheckpointError(
            f"{cfg_path} holds `_class_name`={meta.get('_class_name')!r}, expected {CLASS_NAME!r}."
        )
    if problem in ("malformed_version", "other_major"):
        raise CheckpointError(
            f"{cfg_path} has format version {meta.get('format_version')!r}; this gaffer-nerf reads "
            f"{FORMAT_VERSION.split('.')[0]}.x. Use the gaffer-nerf version that wrote it."
        )
    tensorf = TensoRFConfig(**_tuples(meta["tensorf"]))
    scene = SceneBoxConfig(**_tuples(meta["scene"]))
    gs = meta["grid_size"]
    field = TensoRFVM(tensorf, scene, (int(gs[0]), int(gs[1]), int(gs[2])))
    state = load_file(str(w_path))
    alpha_volume = state.pop("alpha_volume", None)
    alpha_aabb = state.pop("alpha_aabb", None)
    try:
        field.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        raise CheckpointError(f"{w_path} does not match its {CONFIG_NAME}: {exc}") from exc
    field.alpha_volume, field.alpha_aabb = alpha_volume, alpha_aabb
    return field.to(device)


def _tuples(d: dict[str, Any]) -> dict[str, Any]:
    """A config dataclass's fields as read from JSON (untyped values: the dataclass checks them),
    with lists back as the tuples `dataclasses.asdict` wrote them from."""
    return {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
