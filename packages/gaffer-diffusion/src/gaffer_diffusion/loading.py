"""Loading Neural Gaffer weights from local folders (never a model hub).

Three sources (official implementation §1):

1. `load_authors_release(checkpoint, base_model)`: the authors' `checkpoint-80000/` folder (an
   `accelerate` save-state with the UNet state dict only, `model.safetensors` or `pytorch_model.bin`,
   `conv_in.weight` of shape [320, 16, 3, 3], no config) plus a local Zero-1-to-3 XL folder in diffusers
   layout (`unet/`, `vae/`, `image_encoder/`, `scheduler/`) for the VAE, CLIP encoder, scheduler and the UNet
   config, which is built with `in_channels=16`.
2. `load_zero123_xl(base_model)`: Zero-1-to-3 XL alone with the 8 -> 16 `conv_in` surgery (new input
   channels zero-initialised, bias copied): the starting point for training.
3. `load_pretrained(directory)` / `save_pretrained(model, directory)`: our own format, one diffusers /
   transformers folder per network (safetensors + config.json with the true `in_channels`) and a
   `gaffer_model.json` manifest.

Every state dict is checked against the model: the `LoadReport` lists missing, unexpected and mis-shaped
tensors; with `strict=True` (the default) any of them raises `CheckpointMismatchError` before anything is
loaded.
"""

import dataclasses
import datetime
import json
import logging
import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from diffusers.models.autoencoders.autoencoder_kl import AutoencoderKL
from safetensors import SafetensorError
from safetensors.torch import load_file
from transformers import CLIPVisionModelWithProjection

from gaffer_diffusion._choices import MANIFEST_NAME as MANIFEST_NAME  # re-exported
from gaffer_diffusion._schema_header import check_schema_header
from gaffer_diffusion._version import __version__
from gaffer_diffusion.configs import ModelConfig
from gaffer_diffusion.errors import CheckpointMismatchError, CheckpointNotFoundError
from gaffer_diffusion.models.build import config_from_modules, unet_from_config
from gaffer_diffusion.models.model import NeuralGafferModel
from gaffer_diffusion.models.pixel import PixelAutoencoder, is_pixel_config
from gaffer_diffusion.models.surgery import expand_conv_in
from gaffer_diffusion.suggested import SUGGESTION_KEY, SuggestedSampling

logger = logging.getLogger(__name__)

PathLike = str | Path

MANIFEST_SCHEMA = "gaffer.diffusion_model"
MANIFEST_SCHEMA_VERSION = "1.0"

AUTHORS_WEIGHT_FILES = ("model.safetensors", "pytorch_model.bin")
DIFFUSERS_WEIGHT_FILES = ("diffusion_pytorch_model.safetensors", "diffusion_pytorch_model.bin")
_STRIPPABLE_PREFIXES = ("module.", "_orig_mod.", "unet.")

HOW_TO_GET_RELEASE = (
    "Get the authors' release `neural_gaffer_res256_ckpt.zip` (3.19 GB, linked from the Neural Gaffer "
    "project page / GitHub README), unzip it on this machine and pass the `checkpoint-80000/` folder "
    "(or the folder containing it) as `checkpoint`."
)
HOW_TO_GET_BASE = (
    "Get Zero-1-to-3 XL converted to the diffusers layout (folders unet/, vae/, image_encoder/, "
    "scheduler/; the Neural Gaffer README names the copy it uses), download it on a machine with network "
    "access, copy it here and pass it as `base_model`. Nothing is downloaded at run time."
)


@dataclass(frozen=True, kw_only=True)
class TensorMismatch:
    """A tensor present in both the checkpoint and the model with different shapes."""

    name: str
    expected: tuple[int, ...]
    actual: tuple[int, ...]


@dataclass(frozen=True, kw_only=True)
class LoadReport:
    """How a state dict matched the model it was loaded into.

    Attributes:
        source: the file(s) read.
        missing: model tensors absent from the checkpoint.
        unexpected: checkpoint tensors the model does not have.
        mismatched: tensors present in both with different shapes.
        stripped_prefix: a wrapper prefix removed from every key ("module.", "_orig_mod.", ...), or None.
        notes: anything else done while loading (e.g. conv_in surgery).
    """

    source: str
    missing: tuple[str, ...] = ()
    unexpected: tuple[str, ...] = ()
    mismatched: tuple[TensorMismatch, ...] = ()
    stripped_prefix: str | None = None
    notes: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        """True when every model tensor was found with the right shape and nothing was left over."""
        return not (self.missing or self.unexpected or self.mismatched)

    def summary(self, limit: int = 10) -> str:
        """A human-readable multi-line summary (at most `limit` names per list)."""

        def names(items: tuple[str, ...]) -> str:
            more = f", ... (+{len(items) - limit})" if len(items) > limit else ""
            return ", ".join(items[:limit]) + more

        lines = [f"state dict {self.source}: " + ("OK" if self.ok else "does not match the model")]
        if self.missing:
            lines.append(f"  missing ({len(self.missing)}): {names(self.missing)}")
        if self.unexpected:
            lines.append(f"  unexpected ({len(self.unexpected)}): {names(self.unexpected)}")
        for m in self.mismatched[:limit]:
            lines.append(f"  shape mismatch: {m.name}: checkpoint {m.actual}, model {m.expected}")
        if self.stripped_prefix:
            lines.append(f"  stripped key prefix {self.stripped_prefix!r}")
        lines.extend(f"  note: {n}" for n in self.notes)
        return "\n".join(lines)


@dataclass(frozen=True, kw_only=True)
class LoadResult:
    """A loaded model and the report of its UNet state dict."""

    model: NeuralGafferModel
    report: LoadReport


def read_state_dict(path: PathLike) -> dict[str, torch.Tensor]:
    """Read a `.safetensors` file, a diffusers `*.index.json` shard index, or a torch `.bin` (weights only).

    Raises:
        CheckpointNotFoundError: when the file does not exist.
        CheckpointMismatchError: when it cannot be parsed.
    """
    p = Path(path)
    if not p.is_file():
        raise CheckpointNotFoundError(f"weights file `{p.name}`", [p.parent], "Check the path.")
    try:
        if p.name.endswith(".index.json"):
            weight_map: dict[str, str] = json.loads(p.read_text())["weight_map"]
            state: dict[str, torch.Tensor] = {}
            for shard in sorted(set(weight_map.values())):
                state.update(read_state_dict(p.parent / shard))
            return state
        if p.suffix == ".safetensors":
            return load_file(str(p), device="cpu")
        loaded = torch.load(p, map_location="cpu", weights_only=True)
    except (
        OSError,
        RuntimeError,
        ValueError,
        KeyError,
        SafetensorError,
        pickle.UnpicklingError,
    ) as exc:
        raise CheckpointMismatchError(
            f"Could not read weights file {p}: {exc}. Is the download complete (compare its size with "
            "the release) and is it a safetensors / torch state dict?"
        ) from exc
    if (
        isinstance(loaded, dict)
        and "state_dict" in loaded
        and isinstance(loaded["state_dict"], dict)
    ):
        loaded = loaded["state_dict"]
    if not isinstance(loaded, dict):
        raise CheckpointMismatchError(f"{p} holds a {type(loaded).__name__}, not a state dict.")
    return loaded


def _strip_prefix(
    state: dict[str, torch.Tensor], expected: set[str]
) -> tuple[dict[str, torch.Tensor], str | None]:
    if not state or set(state) & expected:
        return state, None
    for prefix in _STRIPPABLE_PREFIXES:
        if all(k.startswith(prefix) for k in state):
            return {k[len(prefix) :]: v for k, v in state.items()}, prefix
    return state, None


def check_state_dict(
    module: torch.nn.Module, state: dict[str, torch.Tensor], *, source: str
) -> tuple[LoadReport, dict[str, torch.Tensor]]:
    """Compare `state` with `module.state_dict()` without loading anything.

    Returns:
        The report and the state dict with any wrapper prefix stripped.
    """
    model_state = module.state_dict()
    expected = set(model_state)
    state, prefix = _strip_prefix(state, expected)
    got = set(state)
    mismatched = tuple(
        TensorMismatch(name=k, expected=tuple(model_state[k].shape), actual=tuple(state[k].shape))
        for k in sorted(expected & got)
        if tuple(model_state[k].shape) != tuple(state[k].shape)
    )
    report = LoadReport(
        source=source,
        missing=tuple(sorted(expected - got)),
        unexpected=tuple(sorted(got - expected)),
        mismatched=mismatched,
        stripped_prefix=prefix,
    )
    return report, state


def load_checked(
    module: torch.nn.Module, state: dict[str, torch.Tensor], *, source: str, strict: bool = True
) -> LoadReport:
    """Load `state` into `module` after checking it; see `check_state_dict`.

    Args:
        module: the target.
        state: the state dict.
        source: where it came from (for the report and errors).
        strict: raise on any mismatch (before loading); otherwise load the matching tensors and log.

    Raises:
        CheckpointMismatchError: with `strict` and a report that is not `ok`.
    """
    report, state = check_state_dict(module, state, source=source)
    if not report.ok:
        if strict:
            raise CheckpointMismatchError(
                report.summary()
                + "\nIs this the right checkpoint for this base model? Pass `strict=False` to load the "
                "matching tensors anyway and inspect the report."
            )
        logger.warning("%s", report.summary())
    bad = {m.name for m in report.mismatched}
    module.load_state_dict({k: v for k, v in state.items() if k not in bad}, strict=False)
    return report


def _find_weights(folder: Path, names: tuple[str, ...]) -> Path | None:
    for name in names:
        if (folder / name).is_file():
            return folder / name
    for name in names:
        index = folder / f"{name}.index.json"
        if index.is_file():
            return index
    return None


def _require_dir(path: Path, what: str, how: str) -> Path:
    if not path.is_dir():
        raise CheckpointNotFoundError(what, [path], how)
    return path


def _read_json(path: Path, what: str, how: str) -> dict[str, Any]:
    if not path.is_file():
        raise CheckpointNotFoundError(what, [path.parent], how)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise CheckpointMismatchError(f"Could not parse {path}: {exc}") from exc
    if not isinstance(data, dict):
        raise CheckpointMismatchError(f"{path} does not hold a JSON object.")
    return data


def _load_vae(folder: Path, how: str) -> AutoencoderKL | PixelAutoencoder:
    config = _read_json(folder / "config.json", "the VAE config `vae/config.json`", how)
    if is_pixel_config(config):
        return PixelAutoencoder.from_config(config).eval()
    if _find_weights(folder, DIFFUSERS_WEIGHT_FILES) is None:
        raise CheckpointNotFoundError(
            "the VAE weights (`diffusion_pytorch_model.safetensors` or `.bin`)", [folder], how
        )
    return AutoencoderKL.from_pretrained(folder, local_files_only=True).eval()


def _load_image_encoder(folder: Path, how: str) -> CLIPVisionModelWithProjection:
    _read_json(
        folder / "config.json", "the CLIP image encoder config `image_encoder/config.json`", how
    )
    if _find_weights(folder, ("model.safetensors", "pytorch_model.bin")) is None:
        raise CheckpointNotFoundError(
            "the CLIP image encoder weights (`model.safetensors` or `pytorch_model.bin`)",
            [folder],
            how,
        )
    encoder = CLIPVisionModelWithProjection.from_pretrained(folder, local_files_only=True).eval()
    _own_aligned_copies(encoder)
    return encoder


def _own_aligned_copies(module: torch.nn.Module) -> None:
    """Give every parameter and buffer of `module` its own freshly allocated storage.

    transformers 5 hands back safetensors weights as views into one file buffer at offsets that are
    not 64-byte aligned; CPU BLAS picks different kernels for unaligned operands, so a loaded CLIP
    then differs from the same weights built in memory by about 2e-6 on some CPUs (AMD EPYC: the
    bit-identity tests in test_loading.py). A copy is aligned and also lets go of the file.
    """
    with torch.no_grad():
        for tensor in [*module.parameters(), *module.buffers()]:
            tensor.data = tensor.data.clone()


def _scheduler_config(base: Path, how: str) -> dict[str, Any]:
    return _read_json(
        base / "scheduler" / "scheduler_config.json",
        "the scheduler config `scheduler/scheduler_config.json`",
        how,
    )


def resolve_authors_checkpoint(checkpoint: PathLike) -> Path:
    """The UNet weights file of the authors' release.

    Accepts the weights file itself, the `checkpoint-80000/` folder, or a folder holding one or more
    `checkpoint-*` folders (the highest step wins).

    Raises:
        CheckpointNotFoundError: naming every place looked in.
    """
    path = Path(checkpoint).expanduser()
    if path.is_file():
        return path
    looked = [path]
    if path.is_dir():
        found = _find_weights(path, AUTHORS_WEIGHT_FILES)
        if found is not None:
            return found
        steps = sorted(
            (d for d in path.glob("checkpoint-*") if d.is_dir()),
            key=lambda d: int(d.name.split("-")[-1]) if d.name.split("-")[-1].isdigit() else -1,
        )
        for d in reversed(steps):
            looked.append(d)
            found = _find_weights(d, AUTHORS_WEIGHT_FILES)
            if found is not None:
                return found
    raise CheckpointNotFoundError(
        "the Neural Gaffer UNet weights (`model.safetensors` or `pytorch_model.bin` in `checkpoint-80000/`)",
        looked,
        HOW_TO_GET_RELEASE,
    )


def _base_unet_config(base: Path) -> dict[str, Any]:
    return _read_json(
        base / "unet" / "config.json",
        "the Zero-1-to-3 XL UNet config `unet/config.json`",
        HOW_TO_GET_BASE,
    )


def load_authors_release(
    checkpoint: PathLike, base_model: PathLike, *, strict: bool = True
) -> LoadResult:
    """Load the released Neural Gaffer checkpoint with the Zero-1-to-3 XL parts it needs.

    Args:
        checkpoint: `checkpoint-80000/` (or its weights file, or the folder holding it).
        base_model: the local Zero-1-to-3 XL diffusers folder (`unet/config.json`, `vae/`,
            `image_encoder/`, `scheduler/`). Its UNet weights are not read.
        strict: raise `CheckpointMismatchError` if the state dict does not match exactly.

    Returns:
        The float32 CPU model and the UNet `LoadReport`.

    Raises:
        CheckpointNotFoundError: a file is missing (the message says which, where, and how to get it).
        CheckpointMismatchError: the state dict does not match (with `strict`).
    """
    weights = resolve_authors_checkpoint(checkpoint)
    base = _require_dir(
        Path(base_model).expanduser(), "the Zero-1-to-3 XL base model folder", HOW_TO_GET_BASE
    )
    unet_cfg = _base_unet_config(base)
    # Neural Gaffer §3.2 / official impl. §1: 16 input channels; their saved config still says 8
    unet_cfg["in_channels"] = 16
    unet = unet_from_config(unet_cfg)
    report = load_checked(unet, read_state_dict(weights), source=str(weights), strict=strict)
    report = dataclasses.replace(
        report, notes=(*report.notes, "UNet config from base_model/unet with in_channels=16")
    )
    vae = _load_vae(base / "vae", HOW_TO_GET_BASE)
    encoder = _load_image_encoder(base / "image_encoder", HOW_TO_GET_BASE)
    sched = _scheduler_config(base, HOW_TO_GET_BASE)
    config = config_from_modules(unet, vae, encoder, sched, name="neural-gaffer-release")
    model = NeuralGafferModel(config=config, unet=unet.eval(), vae=vae, image_encoder=encoder)
    return LoadResult(model=model, report=report)


def load_zero123_xl(base_model: PathLike, *, strict: bool = True) -> LoadResult:
    """Zero-1-to-3 XL with the 8 -> 16 `conv_in` surgery: Neural Gaffer's initialisation for training.

    Args:
        base_model: the local Zero-1-to-3 XL diffusers folder.
        strict: raise if the UNet state dict does not match its config.

    Returns:
        The model (UNet with 16 input channels, channels 8-15 zero, config updated) and the report.

    Raises:
        CheckpointNotFoundError: a file is missing.
        CheckpointMismatchError: the UNet weights do not match its config (with `strict`).
    """
    base = _require_dir(
        Path(base_model).expanduser(), "the Zero-1-to-3 XL base model folder", HOW_TO_GET_BASE
    )
    unet_cfg = _base_unet_config(base)
    weights = _find_weights(base / "unet", DIFFUSERS_WEIGHT_FILES)
    if weights is None:
        raise CheckpointNotFoundError(
            "the Zero-1-to-3 XL UNet weights (`diffusion_pytorch_model.safetensors` or `.bin`)",
            [base / "unet"],
            HOW_TO_GET_BASE,
        )
    unet = unet_from_config(unet_cfg)
    report = load_checked(unet, read_state_dict(weights), source=str(weights), strict=strict)
    old_in = unet.conv_in.in_channels
    expand_conv_in(unet, 16)
    report = dataclasses.replace(
        report,
        notes=(
            *report.notes,
            f"conv_in widened {old_in} -> 16 input channels (new channels zero, bias copied)",
        ),
    )
    vae = _load_vae(base / "vae", HOW_TO_GET_BASE)
    encoder = _load_image_encoder(base / "image_encoder", HOW_TO_GET_BASE)
    sched = _scheduler_config(base, HOW_TO_GET_BASE)
    config = config_from_modules(unet, vae, encoder, sched, name="zero123-xl-16ch")
    model = NeuralGafferModel(config=config, unet=unet.eval(), vae=vae, image_encoder=encoder)
    return LoadResult(model=model, report=report)


def save_pretrained(
    model: NeuralGafferModel, directory: PathLike, *, suggested: SuggestedSampling | None = None
) -> Path:
    """Save in our format: `unet/`, `vae/`, `image_encoder/` (safetensors + config.json), the scheduler
    config, and a `gaffer_model.json` manifest with the full `ModelConfig` and, when given, the
    sampling the model suggests (`gaffer_diffusion.suggested`; without it readers use the paper's).

    Returns:
        The directory.
    """
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    model.unet.save_pretrained(out / "unet", safe_serialization=True)
    model.vae.save_pretrained(out / "vae", safe_serialization=True)
    model.image_encoder.save_pretrained(out / "image_encoder", safe_serialization=True)
    (out / "scheduler").mkdir(exist_ok=True)
    sched = {"_class_name": "DDIMScheduler", **dataclasses.asdict(model.config.scheduler)}
    (out / "scheduler" / "scheduler_config.json").write_text(json.dumps(sched, indent=2))
    manifest = {
        "schema": MANIFEST_SCHEMA,
        "schema_version": MANIFEST_SCHEMA_VERSION,
        "producer": {"package": "gaffer-diffusion", "version": __version__},
        "created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "config": dataclasses.asdict(model.config),
    }
    if suggested is not None:
        manifest[SUGGESTION_KEY] = suggested.to_json()
    (out / MANIFEST_NAME).write_text(json.dumps(manifest, indent=2))
    return out


def load_pretrained(directory: PathLike, *, strict: bool = True) -> LoadResult:
    """Load a model saved by `save_pretrained`.

    Raises:
        CheckpointNotFoundError: a file is missing.
        CheckpointMismatchError: weights do not match their configs, or the manifest's schema is foreign
            or of another major version.
    """
    root = _require_dir(
        Path(directory).expanduser(),
        "a gaffer-diffusion model folder",
        "Create one with `gaffer_diffusion.loading.save_pretrained(model, DIR)`.",
    )
    how = f"{root} should have been written by `gaffer_diffusion.loading.save_pretrained`."
    manifest = _read_json(root / MANIFEST_NAME, f"the manifest `{MANIFEST_NAME}`", how)
    check_schema_header(
        manifest,
        schema=MANIFEST_SCHEMA,
        version=MANIFEST_SCHEMA_VERSION,
        where=str(root / MANIFEST_NAME),
        error=CheckpointMismatchError,
        advice=" Upgrade gaffer-diffusion.",
    )
    unet_cfg = _read_json(root / "unet" / "config.json", "the UNet config `unet/config.json`", how)
    weights = _find_weights(root / "unet", DIFFUSERS_WEIGHT_FILES)
    if weights is None:
        raise CheckpointNotFoundError(
            "the UNet weights `diffusion_pytorch_model.safetensors`", [root / "unet"], how
        )
    unet = unet_from_config(unet_cfg)
    report = load_checked(unet, read_state_dict(weights), source=str(weights), strict=strict)
    vae = _load_vae(root / "vae", how)
    encoder = _load_image_encoder(root / "image_encoder", how)
    sched = _scheduler_config(root, how)
    name = str(manifest.get("config", {}).get("name", "loaded"))
    # what is diffused and whether hints are fed are in no module's config: only the manifest has them
    flags = {}
    for key in ("residual", "hints"):
        flags[key] = manifest.get("config", {}).get(key, False)
        if not isinstance(flags[key], bool):
            raise CheckpointMismatchError(
                f"{root / MANIFEST_NAME}: `config.{key}` is {flags[key]!r}; expected true or false."
            )
    manifest_config = manifest.get("config", {})
    # added in gaffer-tiny 0.5 (log-linear residual); older manifests mean the earlier behaviour
    residual_space = manifest_config.get("residual_space", "display")
    hint_geometry = manifest_config.get("hint_geometry", "silhouette")
    if residual_space not in ("display", "log_linear"):
        raise CheckpointMismatchError(
            f"{root / MANIFEST_NAME}: `config.residual_space` is {residual_space!r}; expected "
            "'display' or 'log_linear'."
        )
    if hint_geometry not in ("silhouette", "estimated"):
        raise CheckpointMismatchError(
            f"{root / MANIFEST_NAME}: `config.hint_geometry` is {hint_geometry!r}; expected "
            "'silhouette' or 'estimated'."
        )
    config = config_from_modules(
        unet, vae, encoder, sched, name=name, hints=flags["hints"], hint_geometry=hint_geometry
    )
    config = dataclasses.replace(config, residual=flags["residual"], residual_space=residual_space)
    model = NeuralGafferModel(config=config, unet=unet.eval(), vae=vae, image_encoder=encoder)
    return LoadResult(model=model, report=report)


def model_config_matches(a: ModelConfig, b: ModelConfig) -> bool:
    """True when two configs describe the same networks (names may differ)."""
    return dataclasses.replace(a, name="") == dataclasses.replace(b, name="")


__all__ = [
    "LoadReport",
    "LoadResult",
    "TensorMismatch",
    "check_state_dict",
    "load_authors_release",
    "load_checked",
    "load_pretrained",
    "load_zero123_xl",
    "model_config_matches",
    "read_state_dict",
    "resolve_authors_checkpoint",
    "save_pretrained",
]
