"""Cheap checks of the command line's files, numbers and outputs, before torch is imported, so a
refusal takes well under a second.

Everything here reads JSON and file headers only, so `gaffer-nerf` refuses a missing folder, a garbled
`field.safetensors`, an out-of-range number or an unwritable output in well under a second, before
it imports torch or loads a model and before any work. Each check raises `ConfigError` (or
`DatasetNotFoundError` / `CheckpointError`) with one line naming the argument and the fix.
"""

import json
import math
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from gaffer_envmap.cli_support import check_not_an_input as shared_not_an_input
from gaffer_envmap.cli_support import check_output_dir as shared_output_dir
from gaffer_envmap.cli_support import check_output_file as shared_output_file
from gaffer_envmap.errors import OutputPathError
from gaffer_nerf.errors import CheckpointError, ConfigError, DatasetError, DatasetNotFoundError

MAX_BATCH_RAYS = 1 << 18
"""Largest `--batch-rays` (64x the paper's 4096): see `check_batch_rays` for the memory it needs."""
SAMPLE_BYTES = 1024
"""Rough bytes one ray sample holds for the backward pass of the paper's field (features of the
density and appearance planes/lines, MLP activations); a scale for messages, not a measurement."""
MAX_ORBIT_FRAMES = 3600
"""Largest `render --orbit` (5 minutes at 12 fps): the frames are held in memory for the GIF."""
MAX_FPS = 100.0
"""GIF frame delays are whole hundredths of a second, so 100 fps is the fastest a GIF can say."""
FIELD_FILES = ("config.json", "field.safetensors")
"""The files of a field folder (`gaffer_nerf.checkpoint`, named here without importing torch)."""
_DEVICE = re.compile(r"^(auto|cpu|mps|cuda(:\d+)?)$")


@dataclass(frozen=True, kw_only=True)
class DataFolderInfo:
    """What `check_data_folder` read from `transforms_train.json` (no image decoded).

    Attributes:
        root: the folder.
        lightings: the gaffer-data lighting indices (empty for a plain NeRF-Synthetic folder).
        has_test: whether `transforms_test.json` exists.
        train_frames: frames of the train split.
        has_lit: whether its first frame lists per-lighting images (`lit`, gaffer-data's).
    """

    root: Path
    lightings: tuple[int, ...]
    has_test: bool
    train_frames: int
    has_lit: bool


def _read_json(path: Path, what: str) -> object:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DatasetError(f"{what} {path} is not valid JSON ({exc}); re-create it.") from exc


def check_data_folder(data: Path, flag: str = "--data") -> DataFolderInfo:
    """A multi-view folder: `transforms_train.json` exists, parses and lists frames.

    Raises:
        DatasetNotFoundError: no such folder or no `transforms_train.json`.
        DatasetError: the file is not JSON or holds no frames.
    """
    path = data / "transforms_train.json"
    if not path.is_file():
        raise DatasetNotFoundError(
            f"`{flag}`: {path} does not exist. A NeRF-Synthetic folder holds transforms_train.json "
            "(and transforms_test.json); gaffer-data writes them with `gaffer-data render-multiview`."
        )
    meta = _read_json(path, f"`{flag}`:")
    frames = meta.get("frames") if isinstance(meta, dict) else None
    if not isinstance(frames, list) or not frames:
        raise DatasetError(
            f"`{flag}`: {path} lists no `frames`; re-render it with `gaffer-data render-multiview`."
        )
    lightings = meta.get("lightings") if isinstance(meta, dict) else None
    indices = tuple(
        int(li["lighting_index"])
        for li in (lightings if isinstance(lightings, list) else [])
        if isinstance(li, dict) and isinstance(li.get("lighting_index"), int)
    )
    return DataFolderInfo(
        root=data,
        lightings=indices,
        has_test=(data / "transforms_test.json").is_file(),
        train_frames=len(frames),
        has_lit=isinstance(frames[0], dict) and bool(frames[0].get("lit")),
    )


def check_lighting(info: DataFolderInfo, flag: str, index: int) -> None:
    """`index` is one of the folder's gaffer-data lightings (per-frame `lit` lists are left to the reader)."""
    if not info.lightings and info.has_lit:
        return
    if not info.lightings:
        raise ConfigError(
            f"`{flag}` is {index}, but {info.root} lists no gaffer-data lightings; pass a "
            "`gaffer-data render-multiview` folder (or `--plain` for a NeRF-Synthetic one)."
        )
    if index not in info.lightings:
        raise ConfigError(
            f"`{flag}` is {index}; {info.root} has lightings {min(info.lightings)}.."
            f"{max(info.lightings)}."
        )


def check_split(info: DataFolderInfo, split: str) -> None:
    """The split's transforms file exists."""
    if split == "test" and not info.has_test:
        raise ConfigError(f"{info.root} has no `transforms_test.json`; pick --split train.")


PRESETS = ("paper", "tiny")


@dataclass(frozen=True, kw_only=True)
class FieldPreset:
    """The preset a field was fitted with, as its folder records it (`relight` takes its own preset
    from it: the paper's steps on a tiny field whitened the object).

    Attributes:
        name: "paper" or "tiny"; None when the folder records none (a field saved
            before the preset was recorded).
        recorded_in: the file it was read from (None: none).
    """

    name: str | None
    recorded_in: Path | None


def read_field_preset(field: Path) -> FieldPreset:
    """The fit's preset recorded with a field: `fit_report.json`'s `preset` (written by `fit`), else
    `relight_report.json`'s `fit_preset` (written by `relight`, carried from its input field).

    A missing, unreadable or unknown value reads as none (the caller says so and picks a default).
    """
    for name, key in (("fit_report.json", "preset"), ("relight_report.json", "fit_preset")):
        path = field / name
        try:
            value = json.loads(path.read_text(encoding="utf-8")).get(key)
        except (OSError, UnicodeDecodeError, json.JSONDecodeError, AttributeError):
            continue
        if value in PRESETS:
            return FieldPreset(name=str(value), recorded_in=path)
    return FieldPreset(name=None, recorded_in=None)


def check_field_folder(field: Path, flag: str = "field") -> None:
    """A `fit` / `relight` output: `config.json` parses and names the class, the weights' header parses.

    Raises:
        CheckpointError: a missing file, another class, or a truncated or garbled safetensors file.
    """
    cfg_path, w_path = field / "config.json", field / "field.safetensors"
    if not cfg_path.is_file() or not w_path.is_file():
        raise CheckpointError(
            f"`{flag}` {field} is not a gaffer-nerf checkpoint (needs config.json and "
            "field.safetensors); make one with `gaffer-nerf fit`."
        )
    try:
        meta = json.loads(cfg_path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CheckpointError(
            f"`{flag}`: {cfg_path} is not valid JSON ({exc}); re-run `gaffer-nerf fit`."
        ) from exc
    if not isinstance(meta, dict) or meta.get("_class_name") != "TensoRFVM":
        found = meta.get("_class_name") if isinstance(meta, dict) else meta
        raise CheckpointError(
            f"`{flag}`: {cfg_path} holds `_class_name`={found!r}, expected 'TensoRFVM'; pass a "
            "folder written by `gaffer-nerf fit` or `relight`."
        )
    _check_safetensors_header(w_path, flag)


def _check_safetensors_header(path: Path, flag: str) -> None:
    """8 bytes of little-endian header length, then that much JSON, then the tensors' bytes."""
    size = path.stat().st_size
    with path.open("rb") as fh:
        head = fh.read(8)
        n = int.from_bytes(head, "little") if len(head) == 8 else -1
        ok = 2 <= n <= size - 8 and n <= 100 * 2**20
        header = fh.read(n) if ok else b""
    try:
        tensors = json.loads(header) if ok else None
    except (UnicodeDecodeError, json.JSONDecodeError):
        tensors = None
    ends = [
        v["data_offsets"][1]
        for k, v in (tensors.items() if isinstance(tensors, dict) else ())
        if k != "__metadata__" and isinstance(v, dict) and len(v.get("data_offsets", ())) == 2
    ]
    if not ends or max(ends) > size - 8 - n:
        raise CheckpointError(
            f"`{flag}`: {path} is truncated or not a safetensors file; re-run `gaffer-nerf fit` "
            "(or the `relight` that wrote it)."
        )


def check_existing(path: Path, flag: str, what: str) -> None:
    """An input file or folder exists."""
    if not path.exists():
        raise ConfigError(f"`{flag}` {path} does not exist; pass {what}.")


def check_output_dir(
    path: Path, flag: str, *, files: Iterable[str] = (), folders: Iterable[str] = ()
) -> None:
    """`path` can be created (or is a folder) and written: no file in its place or above it, and
    none of the `files` it will hold is a folder, none of its `folders` a file (the shared check,
    `gaffer_envmap.cli_support.check_output_dir`, raised as this package's `ConfigError`)."""
    try:
        shared_output_dir(flag, path, files=files, folders=folders)
    except OutputPathError as exc:
        raise ConfigError(str(exc)) from exc


def check_output_file(path: Path, flag: str) -> None:
    """`path` can be written as a file: not a folder, its parent a writable folder (or creatable)."""
    try:
        shared_output_file(flag, path)
    except OutputPathError as exc:
        raise ConfigError(str(exc)) from exc


def check_not_an_input(path: Path, flag: str, inputs: Iterable[tuple[str, Path | None]]) -> None:
    """`path` is none of the command's inputs: writing there would replace them (e.g. a relit field
    written over the field it was relit from)."""
    try:
        shared_not_an_input(flag, path, inputs)
    except OutputPathError as exc:
        raise ConfigError(str(exc)) from exc


def check_device_name(device: str) -> None:
    """`--device` is auto, cpu, mps or cuda[:N] (availability is checked once torch is imported)."""
    if not _DEVICE.match(device):
        raise ConfigError(f"`--device` is {device!r}; pass auto, cpu, cuda, cuda:N or mps.")


def resolve_device(device: str) -> str:
    """The torch device `--device` names, refusing one this machine does not have (imports torch)."""
    import torch

    if device == "auto":
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device.startswith("cuda"):
        if not torch.cuda.is_available():
            build = "a CPU-only torch build" if torch.version.cuda is None else "no visible GPU"
            raise ConfigError(f"`--device` is {device!r} but this machine has {build}; pass cpu.")
        index = int(device.split(":")[1]) if ":" in device else 0
        if index >= torch.cuda.device_count():
            raise ConfigError(
                f"`--device` is {device!r}; this machine has {torch.cuda.device_count()} GPU(s), "
                f"cuda:0..cuda:{torch.cuda.device_count() - 1}."
            )
    if device == "mps" and not torch.backends.mps.is_available():
        raise ConfigError("`--device` is 'mps' but MPS is not available here; pass cpu.")
    return device


def check_batch_rays(batch_rays: int, max_samples: int = 1000) -> None:
    """1 <= `--batch-rays` <= `MAX_BATCH_RAYS`, saying roughly what a larger batch would need."""
    if batch_rays < 1:
        raise ConfigError(f"`--batch-rays` is {batch_rays}; pass rays per step >= 1 (paper: 4096).")
    if batch_rays > MAX_BATCH_RAYS:
        gib = batch_rays * max_samples * SAMPLE_BYTES / 2**30
        raise ConfigError(
            f"`--batch-rays` is {batch_rays}: at up to {max_samples} samples a ray that is roughly "
            f"{gib:,.0f} GiB for one step; pass at most {MAX_BATCH_RAYS} (paper: 4096)."
        )


def check_count(value: int | None, flag: str, *, low: int = 1, high: int | None = None) -> None:
    """An integer flag in [low, high] (None: not given)."""
    if value is None:
        return
    if value < low or (high is not None and value > high):
        span = f"{low}..{high}" if high is not None else f">= {low}"
        raise ConfigError(f"`{flag}` is {value}; pass an int {span}.")


def check_fps(fps: float) -> None:
    """0 < `--fps` <= `MAX_FPS`, finite."""
    if not (math.isfinite(fps) and 0 < fps <= MAX_FPS):
        raise ConfigError(f"`--fps` is {fps!r}; pass frames per second in (0, {MAX_FPS:g}].")
