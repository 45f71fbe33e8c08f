"""Relighting a photo at its own resolution: read it as people save it, frame the object for the
model, and paste the model's result back into the photo at full size.

- `read_photo`: EXIF orientation applied, 8/16-bit, grey, palette, CMYK, JPEG; alpha kept if present.
- `read_mask`: a mask file checked against the photo (same size, neither empty nor full).
- `prepare_photo`: the model's square input (`gaffer_diffusion.preprocess`) and where that square lies
  in the photo (`Framing`).
- `paste_back`: the relit object at the photo's size, composited at its place; pixels outside the mask are
  the input's bytes. `detail="transfer"` (default) applies the model's change of shading to the
  full-resolution photo (`gaffer_diffusion.detail_transfer`); `detail="resize"` upsamples the model's
  output bicubically (the baseline).
- `envmap_backdrop`: the environment map as a pinhole camera at the photo's pose sees it, LDR-encoded, for
  `--background envmap`.
"""

from dataclasses import dataclass
from pathlib import Path
from typing import Literal, assert_never

import numpy as np
import torch
import torch.nn.functional as F
from jaxtyping import Float
from PIL import Image, ImageOps
from torch import Tensor

from gaffer_diffusion import detail_transfer as dt

# the command line's choices, defined where the parser reads them without torch, so a refusal
# comes before torch loads
from gaffer_diffusion._choices import BACKDROP_FOV_DEG as BACKDROP_FOV_DEG
from gaffer_diffusion._choices import Background as Background
from gaffer_diffusion._choices import DetailMode as DetailMode
from gaffer_diffusion._choices import OutputSize as OutputSize
from gaffer_diffusion.errors import InputValueError
from gaffer_diffusion.preprocess import (
    ALPHA_THRESHOLD,
    NG_OBJECT_FRACTION,
    NG_THUMBNAIL,
    PrepareCompat,
    PreparedImage,
    prepare_object_image,
    prepare_object_image_neural_gaffer,
)
from gaffer_envmap.writers import quantize


@dataclass(frozen=True, kw_only=True)
class Photo:
    """A photo as displayed (EXIF orientation applied).

    Attributes:
        rgb_u8: `[H, W, 3]` uint8 sRGB: the bytes pixels outside the mask are written back with.
        rgb: `[H, W, 3]` float32 sRGB in [0, 1] (16-bit sources keep their precision here).
        alpha: `[H, W]` float32 in [0, 1], or None when the file has no alpha channel.
        alpha_u8: `[H, W]` uint8 alpha as read, or None; written back unchanged.
        path: where it was read from.
    """

    rgb_u8: np.ndarray
    rgb: np.ndarray
    alpha: np.ndarray | None
    alpha_u8: np.ndarray | None
    path: Path

    @property
    def size_wh(self) -> tuple[int, int]:
        """`(width, height)` in pixels."""
        return int(self.rgb.shape[1]), int(self.rgb.shape[0])


@dataclass(frozen=True, kw_only=True)
class Framing:
    """Where the model's `size x size` input lies in the photo: its top-left corner and side, in photo
    pixels (float; it may reach past the photo). Model pixel centre `i` sits at photo coordinate
    `top + (i + 0.5) side_y / size - 0.5`."""

    top: float
    left: float
    side_y: float
    side_x: float
    size: int


@dataclass(frozen=True, kw_only=True)
class PreparedPhoto:
    """A photo, its object mask and the model's input cut from it.

    Attributes:
        photo: the photo.
        alpha: `[H, W]` float32 object mask in [0, 1] at the photo's size.
        model_input: the model's square input (`PreparedImage`).
        framing: where that square lies in the photo.
    """

    photo: Photo
    alpha: np.ndarray
    model_input: PreparedImage
    framing: Framing


def _open_oriented(path: Path) -> Image.Image:
    with Image.open(path) as im:
        im.load()
        return ImageOps.exif_transpose(im)


def read_photo(path: str | Path) -> Photo:
    """Read a photo as it is displayed: EXIF orientation applied, any mode converted to sRGB.

    16-bit grey PNGs keep 16-bit precision in `rgb`; palette images with transparency, LA and RGBA keep
    their alpha; CMYK is converted by Pillow.

    Raises:
        InputValueError: when the file cannot be read as an image.
    """
    p = Path(path)
    try:
        im = _open_oriented(p)
    except (OSError, ValueError) as exc:
        raise InputValueError(f"Could not read the image `{p}`: {exc}") from exc
    alpha_u8 = None
    if im.mode in ("I;16", "I;16B", "I;16L", "I"):
        grey = np.asarray(im, np.float64)
        peak = 65535.0 if im.mode != "I" or grey.max() > 255 else 255.0
        g = np.clip(grey / peak, 0.0, 1.0).astype(np.float32)
        rgb = np.repeat(g[..., None], 3, axis=2)
        rgb_u8 = quantize(rgb)
    else:
        has_alpha = im.mode in ("RGBA", "LA", "PA", "RGBa", "La") or "transparency" in im.info
        rgba = np.asarray(im.convert("RGBA"))
        rgb_u8 = np.ascontiguousarray(rgba[..., :3])
        rgb = rgb_u8.astype(np.float32) / 255.0
        if has_alpha:
            alpha_u8 = np.ascontiguousarray(rgba[..., 3])
    alpha = None if alpha_u8 is None else alpha_u8.astype(np.float32) / 255.0
    return Photo(rgb_u8=rgb_u8, rgb=rgb, alpha=alpha, alpha_u8=alpha_u8, path=p)


def read_mask(path: str | Path, photo: Photo) -> np.ndarray:
    """`[H, W]` float32 mask (white = object) of `photo`, read from a file and checked.

    Raises:
        InputValueError: unreadable file, a size other than the photo's, or an empty / full mask.
    """
    p = Path(path)
    try:
        im = _open_oriented(p)
        if im.mode in ("I;16", "I;16B", "I;16L", "I"):
            m = np.asarray(im, np.float64)
            m = (m / (65535.0 if m.max() > 255 else 255.0)).astype(np.float32)
        else:
            m = np.asarray(im.convert("L"), np.float32) / 255.0
    except (OSError, ValueError) as exc:
        raise InputValueError(f"Could not read the mask `{p}`: {exc}") from exc
    (w, h), (mw, mh) = photo.size_wh, (m.shape[1], m.shape[0])
    if (mw, mh) != (w, h):
        raise InputValueError(
            f"The mask `{p}` is {mw}x{mh} but the image `{photo.path}` is {w}x{h} (width x height): "
            "pass a mask of the image's size."
        )
    check_mask(m, f"The mask `{p}`")
    return m


def check_mask(mask: np.ndarray, what: str) -> None:
    """Refuse a mask with no object pixel or with nothing but object pixels (one line each).

    Raises:
        InputValueError: on an all-black or all-white mask.
    """
    fg = mask > ALPHA_THRESHOLD
    if not fg.any():
        raise InputValueError(
            f"{what} is all black (no value above 0.5): it marks no object. White = object; pass "
            "`--mask auto` to estimate one."
        )
    if fg.all():
        raise InputValueError(
            f"{what} is all white: it marks the whole picture as the object, so nothing is left to "
            "place it in. White = object, black = background; pass `--mask auto` to estimate one."
        )


def usable_alpha(photo: Photo) -> np.ndarray | None:
    """The photo's alpha when it can mark the object, else None.

    No alpha channel, or one that is all opaque (every value above 0.5, as many PNG exports write
    it), says nothing about where the object is: the app and the command line then estimate a mask
    (`gaffer_diffusion.automask`) instead of refusing the photo. An alpha with no opaque pixel is
    returned as is, for `check_mask` to refuse (it marks no object).
    """
    if photo.alpha is None or bool((photo.alpha > ALPHA_THRESHOLD).all()):
        return None
    return photo.alpha


def object_alpha(photo: Photo, mask: np.ndarray | None) -> np.ndarray:
    """The object mask: `mask` if given, else the photo's alpha.

    Raises:
        InputValueError: when there is neither (the message names `--mask auto`), or it is empty/full.
    """
    if mask is not None:
        return mask
    if photo.alpha is None:
        raise InputValueError(
            f"`{photo.path}` has no alpha channel and no mask was given: pass `--mask MASK.png` "
            "(white = object), or `--mask auto` for a classical (GrabCut) estimate."
        )
    check_mask(photo.alpha, f"The alpha channel of `{photo.path}`")
    return photo.alpha


def prepare_photo(
    photo: Photo,
    alpha: np.ndarray,
    *,
    size: int,
    compat: PrepareCompat = "default",
    object_fraction: float = 0.75,
) -> PreparedPhoto:
    """The model's square input cut from `photo` and where it lies in the photo.

    Raises:
        InputValueError: on an empty mask or a bad `object_fraction`.
    """
    match compat:
        case "default":
            prepared = prepare_object_image(
                photo.rgb, alpha, size=size, object_fraction=object_fraction
            )
            top, left, bottom, right = prepared.bbox
            h, w = bottom - top, right - left
            side = max(int(np.ceil(max(h, w) / object_fraction)), 1)
            framing = Framing(
                top=float(top - (side - h) // 2),
                left=float(left - (side - w) // 2),
                side_y=float(side),
                side_x=float(side),
                size=size,
            )
        case "neural-gaffer":
            a_u8 = quantize(alpha)
            prepared = prepare_object_image_neural_gaffer(photo.rgb_u8, a_u8, size=size)
            top, left, bottom, right = prepared.bbox  # in the 512 px thumbnail's pixels
            th_img = Image.new("L", photo.size_wh)
            th_img.thumbnail((NG_THUMBNAIL, NG_THUMBNAIL))
            tw, th = th_img.size
            sy, sx = photo.rgb.shape[0] / th, photo.rgb.shape[1] / tw
            h, w = bottom - top, right - left
            side = int(max(w, h) / NG_OBJECT_FRACTION)
            framing = Framing(
                top=(top - (side // 2 - h // 2)) * sy,
                left=(left - (side // 2 - w // 2)) * sx,
                side_y=side * sy,
                side_x=side * sx,
                size=size,
            )
        case _:
            assert_never(compat)
    return PreparedPhoto(photo=photo, alpha=alpha, model_input=prepared, framing=framing)


def _object_box(alpha: np.ndarray, pad: int) -> tuple[int, int, int, int]:
    ys, xs = np.nonzero(alpha > 0)
    h, w = alpha.shape
    return (
        max(int(ys.min()) - pad, 0),
        max(int(xs.min()) - pad, 0),
        min(int(ys.max()) + 1 + pad, h),
        min(int(xs.max()) + 1 + pad, w),
    )


def _resample(
    field: Float[np.ndarray, "S S C"],
    framing: Framing,
    box: tuple[int, int, int, int],
    mode: Literal["bilinear", "bicubic"],
) -> np.ndarray:
    """`field` (model pixels) sampled at the photo pixels of `box` = (top, left, bottom, right)."""
    top, left, bottom, right = box
    s = framing.size
    ys = np.arange(top, bottom, dtype=np.float64)
    xs = np.arange(left, right, dtype=np.float64)
    # photo pixel centre -> model pixel index -> grid_sample's [-1, 1] (align_corners=False)
    iy = (ys + 0.5 - framing.top) * s / framing.side_y - 0.5
    ix = (xs + 0.5 - framing.left) * s / framing.side_x - 0.5
    gy, gx = (2 * iy + 1) / s - 1, (2 * ix + 1) / s - 1
    grid = torch.from_numpy(
        np.stack(np.broadcast_arrays(gx[None, :], gy[:, None]), axis=-1).astype(np.float32)
    )[None]
    src = torch.from_numpy(np.ascontiguousarray(field.transpose(2, 0, 1)))[None]
    out = F.grid_sample(src, grid, mode=mode, padding_mode="border", align_corners=False)
    return out[0].permute(1, 2, 0).numpy()


@dataclass(frozen=True, kw_only=True)
class RelitObject:
    """The relit object at the photo's resolution, inside a box around its mask.

    Attributes:
        box: `(top, left, bottom, right)` of the box in photo pixels (the mask's bounding box, padded).
        rgb: `[bottom - top, right - left, 3]` float32 sRGB in [0, 1]: the relit pixels of the box.
        alpha: `[bottom - top, right - left]` float32 object mask in [0, 1] over the box.
    """

    box: tuple[int, int, int, int]
    rgb: np.ndarray
    alpha: np.ndarray


def relit_object(
    prepared: PreparedPhoto, relit: Float[Tensor, "3 S S"], *, detail: DetailMode = "transfer"
) -> RelitObject:
    """The model's result for `prepared` brought to the photo's resolution, over the object's box.

    `detail="transfer"` applies the model's change of shading to the full-resolution photo
    (`gaffer_diffusion.detail_transfer`); `"resize"` upsamples the model's output bicubically. Shared by
    `paste_back` (the photo relit in place) and `gaffer_diffusion.insert` (the object moved into another
    picture).
    """
    photo, alpha, framing = prepared.photo, prepared.alpha, prepared.framing
    s = framing.size
    scale = max(framing.side_y, framing.side_x) / s  # photo pixels per model pixel
    radius = max(round(2 * scale), 1) if scale > 1 else 0
    box = _object_box(alpha, pad=radius + 2)
    t, l, b, r = box
    crop = photo.rgb[t:b, l:r]
    relit_np = relit.detach().float().clamp(0, 1).permute(1, 2, 0).cpu().numpy()
    match detail:
        case "transfer":
            model_in = prepared.model_input.image[0].permute(1, 2, 0).numpy()
            model_mask = prepared.model_input.mask[0, 0].numpy()
            log_rho = dt.log_shading_ratio(model_in, relit_np, model_mask)
            obj = dt.apply_shading(
                crop, _resample(log_rho, framing, box, "bilinear"), radius=radius
            )
        case "resize":
            obj = np.clip(_resample(relit_np, framing, box, "bicubic"), 0.0, 1.0)
        case _:
            assert_never(detail)
    return RelitObject(box=box, rgb=obj.astype(np.float32), alpha=alpha[t:b, l:r])


def paste_back(
    prepared: PreparedPhoto,
    relit: Float[Tensor, "3 S S"],
    *,
    detail: DetailMode = "transfer",
    backdrop: np.ndarray | None = None,
) -> np.ndarray:
    """The relit object at the photo's size, composited into the photo at its place.

    Args:
        prepared: the photo, its mask and the model's input (`prepare_photo`).
        relit: the model's `[3, S, S]` prediction for `prepared.model_input`, sRGB in [0, 1].
        detail: "transfer" (the model's shading change applied to the full-resolution photo) or "resize"
            (the model's output upsampled bicubically); see `relit_object`.
        backdrop: `[H, W, 3]` float sRGB to composite the object over instead of the photo
            (`envmap_backdrop`), or None to keep the photo's pixels.

    Returns:
        `[H, W, 3]` uint8 (or `[H, W, 4]` when the photo has alpha, which is kept). Without a backdrop,
        every pixel where the mask is 0 holds the input's bytes.
    """
    photo, alpha = prepared.photo, prepared.alpha
    obj = relit_object(prepared, relit, detail=detail)
    t, l, b, r = obj.box
    base = photo.rgb if backdrop is None else np.asarray(backdrop, np.float32)
    a = obj.alpha[..., None]
    out_f = base.copy()
    out_f[t:b, l:r] = a * obj.rgb + (1.0 - a) * base[t:b, l:r]
    out = quantize(out_f)
    if backdrop is None:
        keep = alpha <= 0.0  # outside the mask: the input's bytes, exactly
        out[keep] = photo.rgb_u8[keep]
    if photo.alpha_u8 is not None and backdrop is None:
        out = np.dstack([out, photo.alpha_u8])
    return out


def model_crop(relit: Float[Tensor, "3 S S"]) -> np.ndarray:
    """`[S, S, 3]` uint8 of a model-resolution result (`--output-size model`)."""
    return quantize(relit.permute(1, 2, 0))


def envmap_backdrop(
    radiance_linear: np.ndarray,
    rotation_w2c: np.ndarray,
    *,
    height: int,
    width: int,
    convention: str = "blender",
    fov_deg: float = BACKDROP_FOV_DEG,
    spin_deg: float = 0.0,
) -> np.ndarray:
    """The environment as a pinhole camera sees it, LDR-encoded for display: `[H, W, 3]` in [0, 1].

    A Blender camera (x right, y up, looking down -z) with horizontal field of view `fov_deg` and the
    pose's rotation; each pixel's ray `d_world = R^T d_cam` is turned by `Rz(-spin)` as the lighting
    lookup is (`gaffer_envmap.rotate`), so the backdrop turns with the light. Display encoding: the LDR
    lighting encoding's `clip(E, 0, 1) ** (1 / 2.2)` (`gaffer_envmap.encode.ldr_encode`).

    Args:
        radiance_linear: `[He, We, 3]` linear lat-long map.
        rotation_w2c: `[3, 3]` world -> Blender-camera rotation.
        height: output rows.
        width: output columns.
        convention: the map's lat-long convention.
        fov_deg: horizontal field of view, degrees.
        spin_deg: the light's spin about world up, degrees.
    """
    from gaffer_envmap.conventions import direction_to_uv
    from gaffer_envmap.encode import ldr_encode

    tan = np.tan(np.deg2rad(fov_deg) / 2)
    xs = ((np.arange(width) + 0.5) / width * 2 - 1) * tan
    ys = (1 - (np.arange(height) + 0.5) / height * 2) * tan * height / width
    d_cam = np.stack(np.broadcast_arrays(xs[None, :], ys[:, None], -np.ones((1, 1))), axis=-1)
    d_world = d_cam @ np.asarray(rotation_w2c, np.float64)  # row vectors: R^T d
    a = np.deg2rad(-spin_deg)
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    u, v = direction_to_uv(d_world @ rz.T, convention)
    env = torch.from_numpy(np.array(radiance_linear, np.float32, copy=True)).permute(2, 0, 1)
    we = env.shape[2]
    padded = torch.cat([env[:, :, -1:], env, env[:, :, :1]], dim=2)[None]  # wrap the seam
    gx = ((u * we + 1) / (we + 2)) * 2 - 1
    gy = v * 2 - 1
    grid = torch.from_numpy(np.stack([gx, gy], -1).astype(np.float32))[None]
    rad = F.grid_sample(padded, grid, mode="bilinear", padding_mode="border", align_corners=False)
    return ldr_encode(rad[0]).permute(1, 2, 0).numpy().astype(np.float32)
