"""`gaffer-diffusion check`: validate the authors' release and the Zero-1-to-3 XL base before a long run.

Nothing is loaded into a model and nothing is downloaded: configs are read as JSON, the UNet is built
on the `meta` device (no memory) to list the key names and shapes the checkpoint must have, and the
checkpoint's tensors are read as shapes only (safetensors headers; a `.bin` memory-mapped).

What is checked (official implementation §1, §2):

- `checkpoint-80000/`: the UNet weights (`model.safetensors` or `pytorch_model.bin`); its key names,
  any wrapper prefix (`module.`, `unet.`, `_orig_mod.`), every shape, `conv_in.weight` =
  [320, 16, 3, 3]. The training state accelerate saves beside it (`optimizer.bin`, `scheduler.bin`,
  `scaler.pt`, `random_states_*.pkl`) is listed and ignored.
- the base folder: `model_index.json` (its `cc_projection` is Zero123's pose projection, which
  Neural Gaffer drops), `unet/config.json` (the config the checkpoint is built with, in_channels
  8 -> 16), `vae/` (config with scaling factor 0.18215, weights), `image_encoder/` (config with a
  768-d projection equal to the UNet's cross-attention size, weights), `scheduler/scheduler_config.json`
  (DDIM, 1000 steps, betas 0.00085-0.012 scaled_linear, steps_offset 1, no clipping,
  set_alpha_to_one false, epsilon).

Every problem is one `Finding` saying what is missing or wrong, where it was looked for and how to fix it.
"""

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import torch

from gaffer_diffusion.errors import CheckpointMismatchError, CheckpointNotFoundError
from gaffer_diffusion.loading import (
    AUTHORS_WEIGHT_FILES,
    DIFFUSERS_WEIGHT_FILES,
    HOW_TO_GET_BASE,
    HOW_TO_GET_RELEASE,
    resolve_authors_checkpoint,
)

Level = Literal["ok", "note", "error"]

IGNORED_TRAINING_STATE = ("optimizer.bin", "scheduler.bin", "scaler.pt", "random_states_*.pkl")
"""accelerate's save-state files beside the UNet weights: present in the release, never read."""

_PREFIXES = ("module.", "_orig_mod.", "unet.")


@dataclass(frozen=True, kw_only=True)
class ReleaseExpectations:
    """The numbers the released checkpoint needs (defaults: the real release, official impl. §1-2).

    Attributes:
        conv_in_out: output channels of `conv_in` (320).
        in_channels: input channels of the checkpoint's `conv_in` (16 = 4 noisy + 3 x 4 conditioning).
        projection_dim: CLIP image-embedding size (768 = the UNet's cross-attention size).
        vae_scaling_factor: 0.18215 (applied to the noisy latent only).
        scheduler: scheduler_config.json entries that must match.
    """

    conv_in_out: int = 320
    in_channels: int = 16
    projection_dim: int = 768
    vae_scaling_factor: float = 0.18215
    scheduler: dict[str, Any] = field(
        default_factory=lambda: {
            "_class_name": "DDIMScheduler",
            "num_train_timesteps": 1000,
            "beta_start": 0.00085,
            "beta_end": 0.012,
            "beta_schedule": "scaled_linear",
            "steps_offset": 1,
            "clip_sample": False,
            "set_alpha_to_one": False,
            "prediction_type": "epsilon",
        }
    )


@dataclass(frozen=True, kw_only=True)
class Finding:
    """One line of the check: `level` ok / note / error, what, where (a path) and the fix (errors)."""

    level: Level
    what: str
    where: str = ""
    fix: str = ""

    def line(self) -> str:
        """`[error] what (at where). fix`."""
        where = f" (at {self.where})" if self.where else ""
        fix = f" {self.fix}" if self.fix else ""
        return f"[{self.level}] {self.what}{where}.{fix}"


@dataclass(frozen=True, kw_only=True)
class ReleaseCheck:
    """All findings of `check_release`, in order."""

    findings: tuple[Finding, ...]

    @property
    def ok(self) -> bool:
        """True when nothing is an error."""
        return not any(f.level == "error" for f in self.findings)

    @property
    def errors(self) -> tuple[Finding, ...]:
        """The findings that would stop a run."""
        return tuple(f for f in self.findings if f.level == "error")

    def report(self) -> str:
        """One line per finding and a verdict."""
        lines = [f.line() for f in self.findings]
        verdict = (
            "everything the authors' checkpoint needs is here"
            if self.ok
            else f"{len(self.errors)} problem(s): fix them before a run"
        )
        return "\n".join([*lines, verdict])


def _json(path: Path, what: str, fix: str, out: list[Finding]) -> dict[str, Any] | None:
    if not path.is_file():
        out.append(Finding(level="error", what=f"missing {what}", where=str(path), fix=fix))
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        out.append(
            Finding(level="error", what=f"unreadable {what}: {exc}", where=str(path), fix=fix)
        )
        return None
    if not isinstance(data, dict):
        out.append(Finding(level="error", what=f"{what} is not a JSON object", where=str(path)))
        return None
    return data


def _weights(folder: Path, names: tuple[str, ...], what: str, out: list[Finding]) -> None:
    for name in names:
        if (folder / name).is_file() or (folder / f"{name}.index.json").is_file():
            out.append(Finding(level="ok", what=f"{what}: {name}", where=str(folder)))
            return
    out.append(
        Finding(
            level="error",
            what=f"missing {what} ({' or '.join(f'`{n}`' for n in names)})",
            where=str(folder),
            fix=f"Copy the base model's {folder.name}/ folder complete. {HOW_TO_GET_BASE}",
        )
    )


def _tensor_shapes(path: Path) -> dict[str, tuple[int, ...]]:
    """Key -> shape of a weights file without reading the tensors' data."""
    if path.suffix == ".safetensors":
        from safetensors import safe_open

        with safe_open(str(path), framework="pt") as fh:
            return {k: tuple(fh.get_slice(k).get_shape()) for k in fh.keys()}
    try:
        state = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
    except RuntimeError:  # legacy (non-zip) torch files cannot be memory-mapped
        state = torch.load(path, map_location="cpu", weights_only=True)
    if isinstance(state, dict) and isinstance(state.get("state_dict"), dict):
        state = state["state_dict"]
    if not isinstance(state, dict):
        raise CheckpointMismatchError(f"{path} holds a {type(state).__name__}, not a state dict.")
    return {k: tuple(v.shape) for k, v in state.items() if isinstance(v, torch.Tensor)}


def _check_base(base: Path, exp: ReleaseExpectations, out: list[Finding]) -> dict[str, Any] | None:
    """The base folder's parts; returns its UNet config (or None)."""
    fix = HOW_TO_GET_BASE
    index = _json(base / "model_index.json", "the pipeline index `model_index.json`", fix, out)
    if index is not None:
        for part in ("unet", "vae", "image_encoder", "scheduler"):
            if part not in index:
                out.append(
                    Finding(
                        level="error",
                        what=f"`model_index.json` does not list `{part}`",
                        where=str(base / "model_index.json"),
                        fix="This is not a Zero-1-to-3 XL diffusers folder. " + fix,
                    )
                )
        if "cc_projection" in index:
            out.append(
                Finding(
                    level="note",
                    what="`cc_projection` (Zero123's pose projection) is listed and ignored: "
                    "Neural Gaffer feeds the raw CLIP embedding",
                    where=str(base / "cc_projection"),
                )
            )
    unet_cfg = _json(base / "unet" / "config.json", "the UNet config `unet/config.json`", fix, out)
    if unet_cfg is not None:
        out.append(
            Finding(
                level="ok",
                what=f"UNet config (in_channels {unet_cfg.get('in_channels')}, built with "
                f"{exp.in_channels}; cross_attention_dim {unet_cfg.get('cross_attention_dim')})",
                where=str(base / "unet" / "config.json"),
            )
        )
    vae_cfg = _json(base / "vae" / "config.json", "the VAE config `vae/config.json`", fix, out)
    if vae_cfg is not None:
        factor = vae_cfg.get("scaling_factor", 0.18215)  # diffusers' default when absent
        level: Level = "ok" if factor == exp.vae_scaling_factor else "error"
        out.append(
            Finding(
                level=level,
                what=f"VAE scaling factor {factor}"
                + ("" if level == "ok" else f", expected {exp.vae_scaling_factor}"),
                where=str(base / "vae" / "config.json"),
                fix=""
                if level == "ok"
                else "The checkpoint was trained with SD's VAE (0.18215); use that VAE folder.",
            )
        )
    _weights(base / "vae", DIFFUSERS_WEIGHT_FILES, "VAE weights", out)
    enc_cfg = _json(
        base / "image_encoder" / "config.json",
        "the CLIP image encoder config `image_encoder/config.json`",
        fix,
        out,
    )
    if enc_cfg is not None:
        proj = enc_cfg.get("projection_dim")
        cross = None if unet_cfg is None else unet_cfg.get("cross_attention_dim")
        bad = proj != exp.projection_dim or (cross is not None and proj != cross)
        out.append(
            Finding(
                level="error" if bad else "ok",
                what=f"CLIP projection size {proj}"
                + (
                    f", expected {exp.projection_dim} and the UNet's cross_attention_dim ({cross})"
                    if bad
                    else ""
                ),
                where=str(base / "image_encoder" / "config.json"),
                fix="Use the CLIP ViT-L/14 image encoder with projection of the Zero-1-to-3 XL "
                "release."
                if bad
                else "",
            )
        )
    _weights(
        base / "image_encoder", ("model.safetensors", "pytorch_model.bin"), "CLIP weights", out
    )
    sched = _json(
        base / "scheduler" / "scheduler_config.json",
        "the scheduler config `scheduler/scheduler_config.json`",
        fix,
        out,
    )
    if sched is not None:
        wrong = {k: sched.get(k) for k, v in exp.scheduler.items() if sched.get(k, v) != v}
        out.append(
            Finding(
                level="error" if wrong else "ok",
                what="scheduler config "
                + (
                    "differs: "
                    + ", ".join(
                        f"{k}={v!r} (expected {exp.scheduler[k]!r})" for k, v in wrong.items()
                    )
                    if wrong
                    else "matches the authors' DDIM schedule"
                ),
                where=str(base / "scheduler" / "scheduler_config.json"),
                fix="Restore the base model's scheduler_config.json." if wrong else "",
            )
        )
    return unet_cfg


def _check_unet_keys(
    weights: Path, unet_cfg: dict[str, Any], exp: ReleaseExpectations, out: list[Finding]
) -> None:
    from gaffer_diffusion.models.build import unet_from_config

    try:
        shapes = _tensor_shapes(weights)
    except (OSError, RuntimeError, ValueError, CheckpointMismatchError) as exc:
        out.append(
            Finding(
                level="error",
                what=f"cannot read the UNet weights: {exc}",
                where=str(weights),
                fix="Is the download complete (the zip is 3.19 GB)? " + HOW_TO_GET_RELEASE,
            )
        )
        return
    cfg = {k: v for k, v in unet_cfg.items() if not k.startswith("_")}
    cfg["in_channels"] = exp.in_channels  # their saved config says 8 (official impl. §1)
    with torch.device("meta"):
        unet = unet_from_config(cfg)
    expected = {k: tuple(v.shape) for k, v in unet.state_dict().items()}
    if shapes and not set(shapes) & set(expected):
        for prefix in _PREFIXES:
            if all(k.startswith(prefix) for k in shapes):
                shapes = {k[len(prefix) :]: v for k, v in shapes.items()}
                out.append(
                    Finding(
                        level="note",
                        what=f"every key starts with {prefix!r}; the loader strips it",
                        where=str(weights),
                    )
                )
                break
    missing = sorted(set(expected) - set(shapes))
    extra = sorted(set(shapes) - set(expected))
    mism = [k for k in sorted(set(expected) & set(shapes)) if expected[k] != shapes[k]]
    conv = shapes.get("conv_in.weight")
    want_conv = (exp.conv_in_out, exp.in_channels, 3, 3)
    out.append(
        Finding(
            level="ok" if conv == want_conv else "error",
            what=f"conv_in.weight {list(conv) if conv else 'absent'}"
            + ("" if conv == want_conv else f", expected {list(want_conv)}"),
            where=str(weights),
            fix=""
            if conv == want_conv
            else "This is not Neural Gaffer's UNet (Zero123's own has 8 input channels): pass the "
            "`checkpoint-80000/` folder of `neural_gaffer_res256_ckpt.zip`.",
        )
    )
    if missing or extra or mism:

        def names(keys: list[str]) -> str:
            return ", ".join(keys[:5]) + (f", ... (+{len(keys) - 5})" if len(keys) > 5 else "")

        parts = []
        if missing:
            parts.append(f"{len(missing)} missing ({names(missing)})")
        if extra:
            parts.append(f"{len(extra)} unexpected ({names(extra)})")
        if mism:
            parts.append(
                f"{len(mism)} mis-shaped ("
                + ", ".join(f"{k} {list(shapes[k])} vs {list(expected[k])}" for k in mism[:5])
                + ")"
            )
        out.append(
            Finding(
                level="error",
                what="UNet keys do not match the base UNet config: " + "; ".join(parts),
                where=str(weights),
                fix="The checkpoint and `--base-model` must be the authors' release and its "
                "Zero-1-to-3 XL base.",
            )
        )
    else:
        out.append(
            Finding(
                level="ok",
                what=f"UNet state dict: all {len(expected)} keys with the expected shapes",
                where=str(weights),
            )
        )


def check_release(
    checkpoint: str | Path,
    base_model: str | Path,
    expectations: ReleaseExpectations | None = None,
) -> ReleaseCheck:
    """Check the authors' `checkpoint-80000/` and a Zero-1-to-3 XL base folder (see the module doc).

    Args:
        checkpoint: `checkpoint-80000/`, its weights file, or a folder holding it.
        base_model: the local Zero-1-to-3 XL diffusers folder.
        expectations: the numbers to check against (default: the real release's).

    Returns:
        The findings; `ReleaseCheck.ok` is False when a run would fail.
    """
    exp = expectations or ReleaseExpectations()
    out: list[Finding] = []
    weights: Path | None = None
    try:
        weights = resolve_authors_checkpoint(checkpoint)
        out.append(Finding(level="ok", what=f"UNet weights: {weights.name}", where=str(weights)))
    except CheckpointNotFoundError as exc:
        out.append(
            Finding(
                level="error",
                what="missing the Neural Gaffer UNet weights ("
                + " or ".join(f"`{n}`" for n in AUTHORS_WEIGHT_FILES)
                + " inside `checkpoint-80000/`)",
                where=", ".join(exc.looked_in),
                fix=HOW_TO_GET_RELEASE,
            )
        )
    if weights is not None:
        folder = weights.parent
        present = [
            p.name
            for pattern in IGNORED_TRAINING_STATE
            for p in sorted(folder.glob(pattern))
            if p.is_file()
        ]
        if present:
            out.append(
                Finding(
                    level="note",
                    what="training state present and ignored: " + ", ".join(present),
                    where=str(folder),
                )
            )
    base = Path(base_model).expanduser()
    unet_cfg = None
    if not base.is_dir():
        out.append(
            Finding(
                level="error",
                what="missing the Zero-1-to-3 XL base model folder",
                where=str(base),
                fix=HOW_TO_GET_BASE,
            )
        )
    else:
        unet_cfg = _check_base(base, exp, out)
    if weights is not None and unet_cfg is not None:
        _check_unet_keys(weights, unet_cfg, exp, out)
    return ReleaseCheck(findings=tuple(out))


__all__ = [
    "IGNORED_TRAINING_STATE",
    "Finding",
    "ReleaseCheck",
    "ReleaseExpectations",
    "check_release",
]
