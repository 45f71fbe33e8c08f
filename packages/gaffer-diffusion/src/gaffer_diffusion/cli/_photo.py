"""The photo in and out, for `relight`, `insert`, `prepare` and `normals`: reading a photo and its
object mask (estimated by default when the photo has no usable alpha, as in the app), writing an
estimated mask with the outputs, and turning a model result into the image written (pasted back at
the photo's size, or the model's crop, over an optional environment backdrop)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from gaffer_diffusion.cli._requests import EnvmapLight, Light, OutputLook, PhotoMask
from gaffer_diffusion.errors import ConfigError, InputValueError, MissingDependencyError

if TYPE_CHECKING:
    import numpy as np
    import torch

    from gaffer_diffusion.photo import PreparedPhoto


def _mask_out(out: Path) -> Path:
    """Where an automatic mask is written: beside the output, `OUT.mask.png`."""
    return out.with_name(f"{out.with_suffix('').name}.mask.png")


@contextlib.contextmanager
def write_with_outputs(folder: Path, masks: Sequence[PhotoMask] = ()) -> Iterator[Path]:
    """A staging folder for a command's output files; when the block ends without an error they move
    into `folder` together with the estimated masks of `masks`, else none of them does (an
    estimated `OUT.mask.png` is one of the outputs, complete or absent with them: nothing already
    written is left half-replaced)."""
    from gaffer_diffusion._atomic_dir import staged_files

    with staged_files(folder, ()) as stage:
        yield stage
        for m in masks:
            m.write_mask_into(stage)


def _photo_and_mask(
    sam: Path | None, image: Path, mask: Path | str | None, mask_out: Path
) -> PhotoMask:
    """The photo and its object mask, read and checked before any weights load.

    The mask is `--mask PATH` when given, else the photo's alpha when it marks the object, else an
    estimate: `sam` (`--sam-checkpoint`)'s Segment Anything, or GrabCut (`--mask auto`, and by default for a
    photo without a usable alpha: RGB, or an all-opaque alpha, as the app does). An estimated mask is
    not written here: the caller writes it to `mask_out` with its outputs (`write_with_outputs`).
    """
    from gaffer_diffusion.photo import object_alpha, read_mask, read_photo, usable_alpha
    from gaffer_envmap.writers import quantize

    photo = read_photo(image)
    why = ""
    if sam is None and mask != "auto":
        if isinstance(mask, Path):
            return PhotoMask(photo=photo, alpha=object_alpha(photo, read_mask(mask, photo)))
        if usable_alpha(photo) is not None:
            return PhotoMask(photo=photo, alpha=object_alpha(photo, None))
        why = (
            f"`{image.name}` has no alpha channel"
            if photo.alpha is None
            else f"the alpha channel of `{image.name}` is all opaque"
        )
    from gaffer_diffusion import automask
    from gaffer_diffusion.photo import check_mask

    if sam is not None:
        alpha, how = automask.sam_mask(photo.rgb_u8, sam), f"Segment Anything ({sam.name})"
    else:
        try:
            alpha = automask.grabcut_mask(photo.rgb_u8)
        except MissingDependencyError as exc:
            if not why:
                raise
            raise MissingDependencyError(
                f"{why}, so its object mask is estimated, which needs OpenCV: pip install "
                '"gaffer-diffusion[photo]" (opencv-python-headless), or pass `--mask MASK.png` '
                "(white = object)."
            ) from exc
        except InputValueError as exc:
            if not why:
                raise
            raise InputValueError(
                f"{why}, so its object mask was estimated (GrabCut, a classical fallback that "
                "expects one object roughly in the middle of the photo), but it found no object: "
                "pass `--mask MASK.png` (white = object)."
            ) from exc
        how = "GrabCut (a classical fallback, not a learned segmenter" + (
            ", as `--mask auto`)" if why else ")"
        )
    check_mask(alpha, f"The automatic mask of `{image}`")
    note = (
        f"{why + ': ' if why else ''}mask estimated by {how}, written to {mask_out}: check it, and "
        f"pass a corrected one with `--mask {mask_out}`"
    )
    return PhotoMask(
        photo=photo,
        alpha=alpha,
        note=note,
        estimated=quantize(alpha),
        mask_out=mask_out,
    )


def _backdrop(
    look: OutputLook, light: Light | None, height: int, width: int, fov: float, k: int, n: int
) -> np.ndarray | None:
    """The target environment as the camera sees it (`--background envmap`), or None: the map the
    request read, not read again."""
    if look.background == "input" or not isinstance(light, EnvmapLight):
        return None
    from gaffer_diffusion.photo import envmap_backdrop

    env = light.env
    return envmap_backdrop(
        env.radiance_linear,
        light.pose.rotation,
        height=height,
        width=width,
        convention=env.convention,
        fov_deg=fov,
        spin_deg=k * 360.0 / n if n > 1 else 0.0,
    )


def _finish(
    look: OutputLook,
    prepared: PreparedPhoto,
    relit: torch.Tensor,
    light: Light | None,
    frame: tuple[int, int] = (0, 1),
) -> np.ndarray:
    """One model result as written: pasted back at the photo's size, or the model's crop."""
    import numpy as np

    from gaffer_diffusion.photo import model_crop, paste_back
    from gaffer_envmap.writers import quantize

    k, n = frame
    match look.output_size:
        case "model":
            s = int(relit.shape[-1])
            # the crop sees a narrower field than the photo: its share of the photo's width
            share = prepared.framing.side_x / prepared.photo.size_wh[0]
            fov = float(np.rad2deg(2 * np.arctan(np.tan(np.deg2rad(look.fov) / 2) * share)))
            bd = _backdrop(look, light, s, s, min(fov, 179.0), k, n)
            if bd is None:
                return model_crop(relit)
            m = prepared.model_input.mask[0, 0].numpy()[..., None]
            rgb = relit.clamp(0, 1).permute(1, 2, 0).numpy()
            return quantize(m * rgb + (1 - m) * bd)
        case "input":
            h, w = prepared.alpha.shape
            bd = _backdrop(look, light, h, w, look.fov, k, n)
            return paste_back(prepared, relit, detail=look.detail, backdrop=bd)
        case _:
            raise ConfigError(f"`--output-size` is {look.output_size!r}; expected input or model.")
