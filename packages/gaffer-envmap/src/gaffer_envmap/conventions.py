"""Lat-long (equirectangular) conventions: the one place where pixel <-> direction is defined.

A convention says, in its own world frame, which direction is "up" (the top row), which horizon direction
sits at the centre column u = 0.5, and whether the map is mirrored. With `left = up x centre`, a standard
(photo-like, chirality -1) convention maps

    theta = pi * v                    (polar angle from up; v = 0 top row, v = 1 bottom row)
    phi   = 2 pi (0.5 - u)
    d     = cos(theta) up + sin(theta) (cos(phi) centre + sin(phi) left)

(mirrored conventions use left = centre x up instead), so u = 0.25 looks at `left`, u = 0 and u = 1 at -centre (the seam). Pixel centres sit at
((j + 0.5) / We, (i + 0.5) / He) ("center" alignment, used by every computation here).

World frames: y-up conventions are related to Blender's z-up world by the usual axis change
(x, y, z)_blender -> (x, z, -y)_yup. With that, "blender" and "threejs" describe the same map.

The Neural Gaffer camera-frame layout ("neural-gaffer-camera") lives in Blender's camera frame
(x right, y up, camera looks along -z): centre column = camera right, u = 0.25 = the viewing direction
(what is behind the object), u = 0.75 = towards the viewer, top row = camera up (paper section 3.2;
reference section 4). It is three.js's layout with the camera frame as world.

Figure: docs/conventions.md, generated from these definitions by docs/_scripts/make_figures.py.
"""

from dataclasses import dataclass
from typing import Literal

import numpy as np

from gaffer_envmap.errors import ConventionError, ShapeError

PixelAlignment = Literal["center", "corner"]
"""Where pixel (i, j) sits on the sphere.

- "center": pixel centres at ((j + 0.5)/We, (i + 0.5)/He); the whole sphere tiles into equal-angle cells
  (Blender, three.js, skylibs, the Neural Gaffer world maps). Every gaffer computation uses this.
- "corner": pixel centres at (j/(We-1), i/(He-1)); first/last column both on the seam and first/last row
  on the poles (OpenEXR `envmap` attribute, Mitsuba rows, Filament). Convert with
  `convention_transforms.to_center_alignment` before any math.
"""

Frame = Literal["world", "camera"]

# Blender's z-up world coordinates of a y-up world's axes: column k = image of y-up basis vector k.
_YUP_TO_BLENDER = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], dtype=np.float64)
_IDENTITY = np.eye(3, dtype=np.float64)


@dataclass(frozen=True)
class LatLongConvention:
    """A named lat-long convention.

    Attributes:
        name: registry key.
        up: direction of the top row, in the convention's own world frame.
        centre: horizon direction at u = 0.5, in the convention's own world frame.
        mirrored: True for chirality +1 conventions (pbrt-v3, Filament), whose image is a mirror of a photo.
        file_alignment: the pixel alignment files of that ecosystem use.
        frame: "world" or "camera" (the Neural Gaffer layout is defined in a camera frame).
        to_blender: 3x3 matrix taking the convention's world coordinates to Blender's z-up world.
        source: where the formula comes from.
    """

    name: str
    up: tuple[float, float, float]
    centre: tuple[float, float, float]
    mirrored: bool
    file_alignment: PixelAlignment
    frame: Frame
    to_blender: tuple[tuple[float, ...], ...]
    source: str

    @property
    def left(self) -> np.ndarray:
        """Horizon direction at u = 0.25."""
        up, centre = np.asarray(self.up, float), np.asarray(self.centre, float)
        left = np.cross(up, centre)
        return -left if self.mirrored else left

    @property
    def basis(self) -> np.ndarray:
        """`[3, 3]` rows (centre, left, up) in the convention's world frame."""
        return np.stack([np.asarray(self.centre, float), self.left, np.asarray(self.up, float)])


def _conv(name, up, centre, mirrored, alignment, frame, to_blender, source) -> LatLongConvention:
    return LatLongConvention(
        name=name,
        up=(float(up[0]), float(up[1]), float(up[2])),
        centre=(float(centre[0]), float(centre[1]), float(centre[2])),
        mirrored=mirrored,
        file_alignment=alignment,
        frame=frame,
        to_blender=tuple(tuple(float(x) for x in row) for row in to_blender),
        source=source,
    )


CONVENTIONS: dict[str, LatLongConvention] = {  # name (and aliases below) -> convention
    c.name: c
    for c in (
        _conv(
            "blender",
            (0, 0, 1),
            (1, 0, 0),
            False,
            "center",
            "world",
            _IDENTITY,
            "Blender/Cycles direction_to_equirectangular: u = 0.5 - atan2(y, x)/2pi, z up",
        ),
        _conv(
            "neural-gaffer-camera",
            (0, 1, 0),
            (1, 0, 0),
            False,
            "center",
            "camera",
            _IDENTITY,
            "Neural Gaffer rotated map in Blender camera axes (x right, y up, -z forward)",
        ),
        _conv(
            "threejs",
            (0, 1, 0),
            (1, 0, 0),
            False,
            "center",
            "world",
            _YUP_TO_BLENDER,
            "three.js equirectUv: u = atan2(z, x)/2pi + 0.5, y up",
        ),
        _conv(
            "mitsuba",
            (0, 1, 0),
            (0, 0, 1),
            False,
            "corner",
            "world",
            _YUP_TO_BLENDER,
            "Mitsuba 3 envmap.cpp: u = atan2(x, -z)/2pi, y up (rows at the poles)",
        ),
        _conv(
            "openexr",
            (0, 1, 0),
            (0, 0, 1),
            False,
            "corner",
            "world",
            _YUP_TO_BLENDER,
            "OpenEXR `envmap` latlong / USD DomeLight(Y): lon = +pi at x = min, corner-aligned",
        ),
        _conv(
            "skylibs",
            (0, 1, 0),
            (0, 0, -1),
            False,
            "center",
            "world",
            _YUP_TO_BLENDER,
            "skylibs/envmap and nvdiffrec: u = 0.5 + atan2(x, -z)/2pi, y up",
        ),
        _conv(
            "filament",
            (0, 1, 0),
            (0, 0, 1),
            True,
            "corner",
            "world",
            _YUP_TO_BLENDER,
            "Filament cmgen toRectilinear: mirrored (chirality +1), y up",
        ),
        _conv(
            "pbrt-v3",
            (0, 0, 1),
            (-1, 0, 0),
            True,
            "center",
            "world",
            _IDENTITY,
            "pbrt-v3 InfiniteAreaLight: u = phi/2pi, phi = atan2(y, x) in [0, 2pi), left-handed",
        ),
    )
}
CONVENTIONS["usd"] = CONVENTIONS["openexr"]
CONVENTIONS["nvdiffrec"] = CONVENTIONS["skylibs"]


def get_convention(name: str) -> LatLongConvention:
    """Look a convention up by name.

    Raises:
        ConventionError: for an unknown name; the message lists the known ones.
    """
    try:
        return CONVENTIONS[name]
    except KeyError as exc:
        known = ", ".join(sorted(CONVENTIONS))
        raise ConventionError(f"`convention` {name!r} is unknown; use one of: {known}.") from exc


def uv_to_direction(u: np.ndarray, v: np.ndarray, convention: str = "blender") -> np.ndarray:
    """Unit directions `[..., 3]` (convention's own frame) for image coordinates u, v in [0, 1].

    u runs left -> right, v top -> bottom (v = 0 is the up pole).
    """
    conv = get_convention(convention)
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    theta = np.pi * v
    phi = 2.0 * np.pi * (0.5 - u)  # mirroring lives in `basis` (left = centre x up)
    local = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)
    return local @ conv.basis


def direction_to_uv(
    dirs: np.ndarray, convention: str = "blender"
) -> tuple[np.ndarray | np.float64, np.ndarray | np.float64]:
    """Image coordinates (u in [0, 1), v in [0, 1]) of directions `[..., 3]` (need not be unit); numpy
    scalars for a single direction `[3]`."""
    conv = get_convention(convention)
    d = np.asarray(dirs, dtype=np.float64)
    if d.shape[-1] != 3:
        raise ShapeError("dirs", d.shape, "[..., 3]")
    local = d @ conv.basis.T  # (centre, left, up) components
    norm = np.linalg.norm(local, axis=-1)
    cos_theta = np.clip(local[..., 2] / np.where(norm > 0, norm, 1.0), -1.0, 1.0)
    phi = np.arctan2(local[..., 1], local[..., 0])
    u = 0.5 - phi / (2 * np.pi)
    return np.mod(u, 1.0), np.arccos(cos_theta) / np.pi


def pixel_center_uv(
    height: int, width: int, alignment: PixelAlignment = "center"
) -> tuple[np.ndarray, np.ndarray]:
    """u `[We]` and v `[He]` of pixel centres for a grid."""
    if alignment == "center":
        return (np.arange(width) + 0.5) / width, (np.arange(height) + 0.5) / height
    return np.arange(width) / max(width - 1, 1), np.arange(height) / max(height - 1, 1)


def direction_grid(
    height: int, width: int, convention: str = "blender", alignment: PixelAlignment = "center"
) -> np.ndarray:
    """`[He, We, 3]` float64 unit directions of every pixel centre."""
    u, v = pixel_center_uv(height, width, alignment)
    uu, vv = np.meshgrid(u, v)
    return uv_to_direction(uu, vv, convention)


def row_solid_angle(
    height: int, width: int | None = None, alignment: PixelAlignment = "center"
) -> np.ndarray:
    """Solid angle `[He]` (steradians) of one pixel in each row; the grid sums to 4 pi.

    Solid angle is uniform in (phi, cos theta), so a row between polar angles a < b covers
    (2 pi / We)(cos a - cos b). Corner-aligned rows at the poles cover half a row height.
    """
    width = 2 * height if width is None else width
    if alignment == "center":
        edges = np.arange(height + 1) * (np.pi / height)
    else:
        step = np.pi / max(height - 1, 1)
        edges = np.clip((np.arange(height + 1) - 0.5) * step, 0.0, np.pi)
    return (2 * np.pi / width) * (np.cos(edges[:-1]) - np.cos(edges[1:]))


def solid_angle(
    height: int, width: int | None = None, alignment: PixelAlignment = "center"
) -> np.ndarray:
    """Per-pixel solid angle `[He, We]` (steradians)."""
    width = 2 * height if width is None else width
    return np.repeat(row_solid_angle(height, width, alignment)[:, None], width, axis=1)


def chirality(convention: str) -> int:
    """Sign of up . (d(u=0.25) x d(u=0.5)): -1 for photo-like maps, +1 for mirrored ones."""
    d25 = uv_to_direction(np.array(0.25), np.array(0.5), convention)
    d50 = uv_to_direction(np.array(0.5), np.array(0.5), convention)
    up = np.asarray(get_convention(convention).up, float)
    return int(np.sign(up @ np.cross(d25, d50)))
