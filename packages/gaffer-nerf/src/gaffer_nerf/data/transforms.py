"""NeRF-Synthetic-style multi-view folders (`transforms_{train,test}.json` + PNGs), and gaffer-data's.

The files (Mildenhall et al. 2020) hold `camera_angle_x` (horizontal field of view, radians) and
`frames`, each with `file_path` (relative to the json, ".png" appended when it has no suffix) and
`transform_matrix`, a 4x4 camera-to-world in Blender's world (z up) and OpenGL/Blender camera axes
(x right, y up, the camera looks along -z). Here it becomes `c2w_opencv = c2w_blender @ diag(1,-1,-1,1)`.

gaffer-data's multi-view sets (`gaffer-data render-multiview`) write the same files and add, per frame,
`lit`: `[{lighting_index, file_path}]` (one image per lighting of the object) and at the top level
`lightings`: `[{lighting_index, envmap, flip, yaw_step, num_steps}]`, plus `fl_x`, `fl_y`, `cx`, `cy`.
Lighting 0 is the one the radiance field is fitted to; the others are relighting targets with ground
truth. PNGs are sRGB with straight alpha; they are composited over white as the authors do.
"""

import json
import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from jaxtyping import Float
from PIL import Image
from torch import Tensor

from gaffer_nerf.cameras import Cameras
from gaffer_nerf.errors import DatasetError, DatasetNotFoundError

BLENDER_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True, kw_only=True)
class LightingInfo:
    """One lighting of a multi-view set.

    Attributes:
        lighting_index: the index `LLL` used in file names.
        envmap: the environment map's name (file stem in the pool).
        flip: mirrored horizontally before use (gaffer-envmap `AugmentSpec`).
        yaw_step: rolled by `yaw_step / num_steps` of a turn after the flip.
        num_steps: yaw steps per turn.
        source: the map's file as given to the renderer, when known (gaffer-data manifests).
    """

    lighting_index: int
    envmap: str
    flip: bool = False
    yaw_step: int = 0
    num_steps: int = 1
    source: str | None = None


@dataclass(frozen=True, kw_only=True)
class ViewSet:
    """The images and cameras of one split under one lighting.

    Attributes:
        rgb_srgb: `[V, H, W, 3]` float32 sRGB in [0, 1], composited over white when `alpha` exists.
        alpha: `[V, H, W]` float32 coverage in [0, 1], or None for RGB files.
        cameras: the V cameras.
        names: one label per view (the frame's file path).
        lighting_index: which lighting the images show (None: the files' default `file_path`).
    """

    rgb_srgb: Float[Tensor, "V H W 3"]
    alpha: Float[Tensor, "V H W"] | None
    cameras: Cameras
    names: tuple[str, ...]
    lighting_index: int | None = None

    @property
    def num_views(self) -> int:
        """V."""
        return int(self.rgb_srgb.shape[0])

    def rgb_flat(self) -> Float[Tensor, "N 3"]:
        """Pixels in the order of `cameras.rays()` (view-major, row-major)."""
        return self.rgb_srgb.reshape(-1, 3)

    def select(self, index: list[int]) -> "ViewSet":
        """The views at `index`, in that order (images, alpha, cameras and names together)."""
        i = torch.as_tensor(index, dtype=torch.long)
        return replace(
            self,
            rgb_srgb=self.rgb_srgb[i],
            alpha=None if self.alpha is None else self.alpha[i],
            cameras=self.cameras.select(i),
            names=tuple(self.names[k] for k in index),
        )


@dataclass(frozen=True, kw_only=True)
class MultiViewScene:
    """A multi-view capture: train (and test) views under one lighting, plus the known lightings.

    Attributes:
        root: the folder holding the transforms files.
        train: training views.
        test: held-out views, or None without `transforms_test.json`.
        lightings: the lightings listed by gaffer-data (empty for plain NeRF-Synthetic folders).
    """

    root: Path
    train: ViewSet
    test: ViewSet | None
    lightings: tuple[LightingInfo, ...] = ()

    def lighting(self, index: int) -> LightingInfo:
        """The lighting with `lighting_index == index`.

        Raises:
            DatasetError: when the scene lists no such lighting.
        """
        for li in self.lightings:
            if li.lighting_index == index:
                return li
        raise DatasetError(
            f"`lighting_index`={index} is not among the scene's lightings "
            f"{[li.lighting_index for li in self.lightings]} ({self.root})."
        )


def read_rgba(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """An 8-bit image as float32 `[H, W, 3]` sRGB in [0, 1] and `[H, W]` alpha (None without alpha)."""
    if not path.is_file():
        raise DatasetNotFoundError(f"Image {path} does not exist; check the frame's `file_path`.")
    with Image.open(path) as im:
        has_alpha = im.mode in ("RGBA", "LA") or "transparency" in im.info
        arr = np.asarray(im.convert("RGBA" if has_alpha else "RGB"), dtype=np.float32) / 255.0
    if has_alpha:
        return arr[..., :3], arr[..., 3]
    return arr, None


def composite_white(rgb: np.ndarray, alpha: np.ndarray | None) -> np.ndarray:
    """Straight-alpha sRGB over white: rgb a + (1 - a) (what the authors and TensoRF's loader do)."""
    if alpha is None:
        return rgb
    return rgb * alpha[..., None] + (1.0 - alpha[..., None])


def _frame_path(base: Path, file_path: str) -> Path:
    p = base / file_path
    return p if p.suffix else p.with_suffix(".png")


def read_transforms_split(
    json_path: str | Path, *, lighting_index: int | None = None, downscale: int = 1
) -> ViewSet:
    """Read one `transforms_{split}.json` and its images.

    Args:
        json_path: the transforms file.
        lighting_index: for gaffer-data sets, which lighting's images to load (from each frame's
            `lit` list); None loads `file_path`.
        downscale: integer factor to shrink the images by (box filter), focal scaled to match.

    Returns:
        The `ViewSet`.

    Raises:
        DatasetNotFoundError: missing json or image.
        DatasetError: malformed json (missing keys, wrong matrix shape, mixed image sizes, no `lit`
            entry for `lighting_index`).
        CameraError: NaN/Inf or non-rigid poses.
    """
    path = Path(json_path)
    if not path.is_file():
        raise DatasetNotFoundError(
            f"{path} does not exist. A NeRF-Synthetic folder holds transforms_train.json (and "
            "transforms_test.json); gaffer-data writes them with `gaffer-data render-multiview`."
        )
    try:
        meta = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path} is not valid JSON: {exc}") from exc
    frames = meta.get("frames")
    if not isinstance(frames, list) or not frames:
        raise DatasetError(f"{path} has no `frames` list (or it is empty).")
    if downscale < 1:
        raise DatasetError(f"`downscale`={downscale} must be an integer >= 1.")
    base = path.parent
    images, alphas, c2ws, names = [], [], [], []
    for k, frame in enumerate(frames):
        if "transform_matrix" not in frame or "file_path" not in frame:
            raise DatasetError(
                f"{path}: frame {k} lacks `transform_matrix` or `file_path`; both are required."
            )
        file_path = frame["file_path"]
        if lighting_index is not None:
            lit = {int(x["lighting_index"]): x["file_path"] for x in frame.get("lit") or []}
            if lighting_index not in lit:
                raise DatasetError(
                    f"{path}: frame {k} has no image for `lighting_index`={lighting_index} (its "
                    f"`lit` list has {sorted(lit)}). Plain NeRF-Synthetic folders have one lighting: "
                    "pass lighting_index=None."
                )
            file_path = lit[lighting_index]
        m = np.asarray(frame["transform_matrix"], dtype=np.float64)
        if m.shape != (4, 4):
            raise DatasetError(
                f"{path}: frame {k} `transform_matrix` has shape {m.shape}, expected (4, 4)."
            )
        rgb, alpha = read_rgba(_frame_path(base, file_path))
        if downscale > 1:
            rgb = _box_down(rgb, downscale)
            alpha = None if alpha is None else _box_down(alpha, downscale)
        images.append(composite_white(rgb, alpha))
        alphas.append(alpha)
        c2ws.append(m @ BLENDER_TO_OPENCV)
        names.append(str(file_path))
    shapes = {im.shape for im in images}
    if len(shapes) != 1:
        raise DatasetError(f"{path}: images have different sizes {sorted(shapes)}; resize them.")
    h, w = images[0].shape[:2]
    fx, fy, cx, cy = _intrinsics(meta, path, w, h, downscale)
    v = len(images)
    with_alpha = all(a is not None for a in alphas)
    return ViewSet(
        rgb_srgb=torch.from_numpy(np.stack(images)).float(),
        alpha=torch.from_numpy(np.stack(alphas)).float() if with_alpha else None,  # type: ignore[arg-type]
        cameras=Cameras(
            c2w_opencv=torch.from_numpy(np.stack(c2ws)).float(),
            focal_px=torch.tensor([[fx, fy]] * v, dtype=torch.float32),
            principal_px=torch.tensor([[cx, cy]] * v, dtype=torch.float32),
            width=w,
            height=h,
        ),
        names=tuple(names),
        lighting_index=lighting_index,
    )


def _box_down(x: np.ndarray, f: int) -> np.ndarray:
    h, w = x.shape[0] // f, x.shape[1] // f
    x = x[: h * f, : w * f]
    return x.reshape(h, f, w, f, *x.shape[2:]).mean(axis=(1, 3))


def _intrinsics(
    meta: dict[str, object], path: Path, w: int, h: int, downscale: int
) -> tuple[float, float, float, float]:
    if "fl_x" in meta:
        s = 1.0 / downscale
        fx = float(meta["fl_x"]) * s  # type: ignore[arg-type]
        fy = float(meta.get("fl_y", meta["fl_x"])) * s  # type: ignore[arg-type]
        cx = float(meta.get("cx", w * downscale / 2)) * s  # type: ignore[arg-type]
        cy = float(meta.get("cy", h * downscale / 2)) * s  # type: ignore[arg-type]
        return fx, fy, cx, cy
    if "camera_angle_x" not in meta:
        raise DatasetError(
            f"{path} has neither `camera_angle_x` nor `fl_x`; add the field of view."
        )
    angle = float(meta["camera_angle_x"])  # type: ignore[arg-type]
    if not 0 < angle < math.pi:
        raise DatasetError(f"{path}: `camera_angle_x`={angle} must be in (0, pi) radians.")
    f = 0.5 * w / math.tan(0.5 * angle)
    return f, f, w / 2.0, h / 2.0


def _lightings(meta: dict[str, object]) -> tuple[LightingInfo, ...]:
    out = []
    for x in meta.get("lightings") or []:  # type: ignore[union-attr]
        out.append(
            LightingInfo(
                lighting_index=int(x["lighting_index"]),
                envmap=str(x["envmap"]),
                flip=bool(x.get("flip", False)),
                yaw_step=int(x.get("yaw_step", 0)),
                num_steps=int(x.get("num_steps", 1)),
                source=x.get("source"),
            )
        )
    return tuple(out)


def read_transforms_folder(
    root: str | Path, *, lighting_index: int | None = None, downscale: int = 1
) -> MultiViewScene:
    """Read `transforms_train.json` and, when present, `transforms_test.json` of a folder.

    Args:
        root: the folder (a NeRF-Synthetic scene or a gaffer-data object folder).
        lighting_index: gaffer-data sets: the lighting to load (0 = the fitting lighting); None
            loads each frame's `file_path`.
        downscale: integer image downscaling factor.

    Returns:
        The `MultiViewScene`.

    Example:
        >>> scene = read_transforms_folder("lego")  # doctest: +SKIP
    """
    root = Path(root)
    train = read_transforms_split(
        root / "transforms_train.json", lighting_index=lighting_index, downscale=downscale
    )
    test_path = root / "transforms_test.json"
    test = (
        read_transforms_split(test_path, lighting_index=lighting_index, downscale=downscale)
        if test_path.is_file()
        else None
    )
    meta = json.loads((root / "transforms_train.json").read_text())
    return MultiViewScene(root=root, train=train, test=test, lightings=_lightings(meta))
