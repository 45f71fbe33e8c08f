"""The photo in and out, for `relight` and `prepare`: the mask flags (`--mask auto`,
`--sam-checkpoint`, `--background`), reading a photo and its object mask, and turning a model result
into the image written (pasted back at the photo's size, or the model's crop, over an optional
environment backdrop)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from gaffer_diffusion.cli._common import _save_png
from gaffer_diffusion.cli._lighting import _pose
from gaffer_diffusion.errors import ConfigError, MissingDependencyError

if TYPE_CHECKING:
    import numpy as np
    import torch

    from gaffer_diffusion.photo import Photo, PreparedPhoto


def _mask_out(out: Path) -> Path:
    """Where an automatic mask is written: beside the output, `OUT.mask.png`."""
    return out.with_name(f"{out.with_suffix('').name}.mask.png")


def _check_photo_flags(args: argparse.Namespace) -> None:
    """`--mask auto` / `--sam-checkpoint` / `--background` refused early, before any input is read."""
    sam = getattr(args, "sam_checkpoint", None)
    if sam is not None:
        if args.mask is not None:
            raise ConfigError("Pass `--mask` or `--sam-checkpoint`, not both.")
        import importlib.util

        if importlib.util.find_spec("segment_anything") is None:
            raise MissingDependencyError(
                "`--sam-checkpoint` needs segment-anything, which is not installed: "
                "pip install segment-anything (or use `--mask auto`, the classical GrabCut fallback)."
            )
    if args.mask == "auto":
        from gaffer_diffusion.automask import require_opencv

        require_opencv()
    if getattr(args, "background", "input") == "envmap":
        if args.envmap is None and getattr(args, "envmaps", None) is None:
            raise ConfigError(
                "`--background envmap` shows the target environment: pass it with `--envmap ENV.exr` "
                "(pre-encoded `--ldr/--hdr` maps cannot be shown)."
            )
        if not 1.0 <= args.fov < 180.0:
            raise ConfigError(f"`--fov` is {args.fov}; expected degrees in [1, 180).")


def _photo_and_mask(
    args: argparse.Namespace, image: Path, mask: Path | str | None, mask_out: Path
) -> tuple[Photo, np.ndarray, str]:
    """The photo and its object mask, read and checked before any weights load, and a note on the mask
    for the report (an automatic mask is written to `mask_out`)."""
    import numpy as np

    from gaffer_diffusion.photo import object_alpha, read_mask, read_photo

    photo = read_photo(image)
    sam = getattr(args, "sam_checkpoint", None)
    if sam is None and mask != "auto":
        m = read_mask(mask, photo) if isinstance(mask, Path) else None
        return photo, object_alpha(photo, m), ""
    from gaffer_diffusion import automask
    from gaffer_diffusion.photo import check_mask

    if sam is not None:
        alpha, how = automask.sam_mask(photo.rgb_u8, sam), f"Segment Anything ({sam.name})"
    else:
        alpha = automask.grabcut_mask(photo.rgb_u8)
        how = "--mask auto, GrabCut: a classical fallback, not a learned segmenter"
    check_mask(alpha, f"The automatic mask of `{image}`")
    _save_png(mask_out, np.round(np.clip(alpha, 0, 1) * 255).astype(np.uint8))
    note = (
        f"mask ({how}) written to {mask_out}: check it, and pass a corrected one with "
        f"`--mask {mask_out}`"
    )
    return photo, alpha, note


def _backdrop(
    args: argparse.Namespace,
    envmap: Path | None,
    height: int,
    width: int,
    fov: float,
    k: int,
    n: int,
) -> np.ndarray | None:
    """The target environment as the camera sees it (`--background envmap`), or None."""
    if args.background == "input" or envmap is None:
        return None
    from gaffer_diffusion.photo import envmap_backdrop
    from gaffer_envmap.io import read_envmap

    env = read_envmap(envmap, sanitize=args.sanitize)
    return envmap_backdrop(
        env.radiance_linear,
        _pose(args).rotation,
        height=height,
        width=width,
        convention=env.convention,
        fov_deg=fov,
        spin_deg=k * 360.0 / n if n > 1 else 0.0,
    )


def _finish(
    args: argparse.Namespace,
    prepared: PreparedPhoto,
    relit: torch.Tensor,
    envmap: Path | None,
    frame: tuple[int, int] = (0, 1),
) -> np.ndarray:
    """One model result as written: pasted back at the photo's size, or the model's crop."""
    import numpy as np

    from gaffer_diffusion.photo import model_crop, paste_back

    k, n = frame
    match args.output_size:
        case "model":
            s = int(relit.shape[-1])
            # the crop sees a narrower field than the photo: its share of the photo's width
            share = prepared.framing.side_x / prepared.photo.size_wh[0]
            fov = float(np.rad2deg(2 * np.arctan(np.tan(np.deg2rad(args.fov) / 2) * share)))
            bd = _backdrop(args, envmap, s, s, min(fov, 179.0), k, n)
            if bd is None:
                return model_crop(relit)
            m = prepared.model_input.mask[0, 0].numpy()[..., None]
            rgb = relit.clamp(0, 1).permute(1, 2, 0).numpy()
            return np.round((m * rgb + (1 - m) * bd) * 255).astype(np.uint8)
        case "input":
            h, w = prepared.alpha.shape
            bd = _backdrop(args, envmap, h, w, args.fov, k, n)
            return paste_back(prepared, relit, detail=args.detail, backdrop=bd)
        case _:
            raise ConfigError(f"`--output-size` is {args.output_size!r}; expected input or model.")
