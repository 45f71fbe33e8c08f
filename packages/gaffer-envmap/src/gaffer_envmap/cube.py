"""Cube-face <-> lat-long conversion in OpenEXR's cube-map layout.

Layout (OpenEXR `ImfEnvmap.cpp`, `CubeMap::pixelPosition` / `CubeMap::direction`): one image of
`N` x `6N` pixels (`[6N, N, C]` as an array), faces stacked top to bottom in the order
+X, -X, +Y, -Y, +Z, -Z of OpenEXR's y-up world. Each face is seen from inside the cube, unmirrored.
With `a = 2 col / (N - 1) - 1` (-1 at the left column, +1 at the right) and
`b = 2 row / (N - 1) - 1` (-1 at the top row of the face, +1 at its bottom), the pixel looks along

    +X: ( 1, -b,  a)    -X: (-1, -b, -a)
    +Y: ( a,  1, -b)    -Y: ( a, -1,  b)
    +Z: (-a, -b,  1)    -Z: ( a, -b, -1)

Faces are corner-aligned: the outermost pixel centres lie exactly on the cube edges (OpenEXR maps
`positionInFace` 0..N-1 to -1..+1), so neighbouring faces repeat their shared edge. Sampling a face
with clamp-to-edge bilinear interpolation is therefore exact at the seams.

The lat-long side uses `gaffer_envmap.conventions`: any world-frame convention is converted to the
OpenEXR frame through its `to_blender` matrix, so `cube_to_latlong(..., convention="blender")` yields
a Blender-convention map directly. OpenEXR's own lat-long files use convention "openexr" with
"corner" alignment.
"""

import numpy as np

from gaffer_envmap.conventions import direction_to_uv, get_convention, uv_to_direction
from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.errors import ConventionError, ShapeError

__all__ = ["FACE_ORDER", "cube_face_directions", "cube_to_latlong", "latlong_to_cube"]

_ROWS_PER_BLOCK = 64

FACE_ORDER = ("+x", "-x", "+y", "-y", "+z", "-z")
"""Order of the faces, top to bottom, in OpenEXR's cube-map image."""

# Per face: direction = _FACE_MATRIX[f] @ (a, b, 1). Signed permutations, so the inverse is the
# transpose: (a, b, 1) = _FACE_MATRIX[f].T @ (direction / |major axis component|).
_FACE_MATRIX = np.array(
    [
        [[0, 0, 1], [0, -1, 0], [1, 0, 0]],  # +X: ( 1, -b,  a)
        [[0, 0, -1], [0, -1, 0], [-1, 0, 0]],  # -X: (-1, -b, -a)
        [[1, 0, 0], [0, 0, 1], [0, -1, 0]],  # +Y: ( a,  1, -b)
        [[1, 0, 0], [0, 0, -1], [0, 1, 0]],  # -Y: ( a, -1,  b)
        [[-1, 0, 0], [0, -1, 0], [0, 0, 1]],  # +Z: (-a, -b,  1)
        [[1, 0, 0], [0, -1, 0], [0, 0, -1]],  # -Z: ( a, -b, -1)
    ],
    dtype=np.float64,
)


def _frame_to_openexr(convention: str) -> np.ndarray:
    """3x3 taking directions in `convention`'s world frame to OpenEXR's y-up frame."""
    conv, exr = get_convention(convention), get_convention("openexr")
    if conv.frame != "world":
        raise ConventionError(
            f"`convention` {convention!r} is a camera-frame layout; cube maps live in a world "
            "frame. Convert the map to a world convention first (e.g. 'blender')."
        )
    return np.asarray(exr.to_blender).T @ np.asarray(conv.to_blender)


def _face_coords(face_size: int, offsets: np.ndarray) -> np.ndarray:
    """Face coordinate (-1..1, corner-aligned) of every pixel plus each sub-sample offset: `[N, S]`."""
    step = 2.0 / (face_size - 1) if face_size > 1 else 0.0
    centres = np.arange(face_size) * step - 1.0
    return centres[:, None] + offsets[None, :] * step


def _sub_offsets(supersample: int) -> np.ndarray:
    """`[S]` stratified sub-sample offsets in pixel units, centred on 0."""
    return (np.arange(supersample) + 0.5) / supersample - 0.5


def cube_face_directions(face_size: int) -> np.ndarray:
    """Unit directions (OpenEXR y-up frame) of every pixel of a cube-map image.

    Args:
        face_size: N, the face width in pixels.

    Returns:
        `[6N, N, 3]` float64 unit vectors, laid out like the cube-map image.

    Example:
        >>> d = cube_face_directions(3)
        >>> d[1, 1].tolist(), d[4 * 3 + 1, 1].tolist()  # centres of +X and +Z
        ([1.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    """
    _check_size("face_size", face_size)
    coord = _face_coords(face_size, np.zeros(1))[:, 0]
    b, a = np.meshgrid(coord, coord, indexing="ij")  # [N, N] row, column coordinates
    abc = np.stack([a, b, np.ones_like(a)], axis=-1)  # [N, N, 3]
    dirs = np.einsum("fij,rcj->frci", _FACE_MATRIX, abc)  # [6, N, N, 3]
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    return dirs.reshape(6 * face_size, face_size, 3)


def _direction_to_cube(dirs: np.ndarray, face_size: int) -> tuple[np.ndarray, ...]:
    """Face index, row and column (continuous, 0..N-1) of OpenEXR-frame directions `[..., 3]`.

    Face selection follows `CubeMap::faceAndPixelPosition`: ties go to X, then Y.
    """
    ax, ay, az = np.abs(dirs[..., 0]), np.abs(dirs[..., 1]), np.abs(dirs[..., 2])
    is_x = (ax >= ay) & (ax >= az)
    is_y = ~is_x & (ay >= az)
    axis = np.where(is_x, 0, np.where(is_y, 1, 2))
    major = np.take_along_axis(dirs, axis[..., None], axis=-1)[..., 0]
    face = 2 * axis + (major < 0)
    scaled = dirs / np.where(major == 0, 1.0, np.abs(major))[..., None]
    abc = np.zeros_like(scaled)
    for f in range(6):
        mask = face == f
        abc[mask] = scaled[mask] @ _FACE_MATRIX[f]  # (A_f^T d) as a row vector
    half = (face_size - 1) / 2.0
    col = np.clip((abc[..., 0] + 1.0) * half, 0.0, face_size - 1)
    row = np.clip((abc[..., 1] + 1.0) * half, 0.0, face_size - 1)
    return face, row, col


def _bilinear(
    image: np.ndarray, rows: np.ndarray, cols: np.ndarray, layer: np.ndarray | int = 0
) -> np.ndarray:
    """Clamp-to-edge bilinear lookup of `image` `[L, H, W, C]` in `layer` at continuous `rows`, `cols`.

    Indices are clamped inside the layer, so a cube face never blends with its neighbour in the
    stacked image.
    """
    h, w = image.shape[1:3]
    r0 = np.clip(np.floor(rows).astype(np.int64), 0, max(h - 2, 0))
    c0 = np.clip(np.floor(cols).astype(np.int64), 0, max(w - 2, 0))
    r1, c1 = np.minimum(r0 + 1, h - 1), np.minimum(c0 + 1, w - 1)
    fr = np.clip(rows - r0, 0.0, 1.0)[..., None]
    fc = np.clip(cols - c0, 0.0, 1.0)[..., None]
    top = image[layer, r0, c0] * (1 - fc) + image[layer, r0, c1] * fc
    bottom = image[layer, r1, c0] * (1 - fc) + image[layer, r1, c1] * fc
    return top * (1 - fr) + bottom * fr


def _check_size(name: str, value: int) -> None:
    if int(value) != value or value < 1:
        raise ShapeError(name, value, "a positive integer")


def _check_faces(faces_img: np.ndarray) -> np.ndarray:
    arr = np.asarray(faces_img)
    if arr.ndim != 3 or arr.shape[2] not in (3, 4) or arr.shape[0] != 6 * arr.shape[1]:
        raise ShapeError(
            "faces_img",
            arr.shape,
            "[6N, N, 3] or [6N, N, 4] (OpenEXR cube layout: +X, -X, +Y, -Y, +Z, -Z stacked)",
            "Read cube maps with `gaffer_envmap.io.read_image_array`.",
        )
    return arr[..., :3].astype(np.float64)


def cube_to_latlong(
    faces_img: np.ndarray,
    out_height: int,
    *,
    convention: str = "openexr",
    supersample: int = 2,
) -> EnvironmentMap:
    """Resample an OpenEXR-layout cube map to a centre-aligned lat-long map.

    Each output pixel averages `supersample`² stratified sub-samples, weighted by solid angle
    (sin of the polar angle), each a clamp-to-edge bilinear lookup in its face.

    Args:
        faces_img: `[6N, N, 3|4]` cube-map image (alpha ignored), OpenEXR layout.
        out_height: He of the result; the width is 2 He.
        convention: lat-long convention of the result (any world-frame convention of
            `gaffer_envmap.conventions`); default "openexr" (y up, u = 0.5 looks at +Z).
        supersample: sub-samples per output pixel along each axis (1 = point sampling).

    Returns:
        `EnvironmentMap` `[He, 2 He, 3]`, alignment "center", in `convention`.

    Raises:
        ShapeError: bad `faces_img` shape, `out_height` or `supersample`.
        ConventionError: unknown or camera-frame `convention`.

    Example:
        >>> env = cube_to_latlong(np.ones((24, 4, 3), np.float32), 4)
        >>> env.radiance_linear.shape, float(env.radiance_linear.mean())
        ((4, 8, 3), 1.0)
    """
    faces = _check_faces(faces_img)
    _check_size("out_height", out_height)
    _check_size("supersample", supersample)
    n, s = faces.shape[1], int(supersample)
    faces = faces.reshape(6, n, n, 3)
    he, we = int(out_height), 2 * int(out_height)
    to_exr = _frame_to_openexr(convention)
    offsets = _sub_offsets(s)
    u = ((np.arange(we)[:, None] + 0.5 + offsets[None, :]) / we).reshape(-1)  # [We*S]
    out = np.empty((he, we, 3), np.float32)
    for start in range(0, he, _ROWS_PER_BLOCK):  # bounded memory for large outputs
        rows = np.arange(start, min(start + _ROWS_PER_BLOCK, he))
        v = ((rows[:, None] + 0.5 + offsets[None, :]) / he).reshape(-1)  # [rows*S]
        vv, uu = np.meshgrid(v, u, indexing="ij")
        dirs = uv_to_direction(uu, vv, convention) @ to_exr.T
        face, row, col = _direction_to_cube(dirs, n)
        samples = _bilinear(faces, row, col, face)  # [rows*S, We*S, 3]
        weight = np.sin(np.pi * v)[:, None, None]  # solid-angle density of each sub-row
        num = (samples * weight).reshape(len(rows), s, we, s, 3).sum(axis=(1, 3))
        den = weight.reshape(len(rows), s).sum(axis=1)[:, None, None] * s
        out[rows] = (num / den).astype(np.float32)
    return EnvironmentMap(radiance_linear=out, convention=convention, alignment="center")


def _sample_latlong(env: EnvironmentMap, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear lookup of `env` at (u, v); periodic in u for centre-aligned maps."""
    src = env.radiance_linear.astype(np.float64)
    he, we = src.shape[:2]
    if env.alignment == "corner":
        return _bilinear(src[None], v * (he - 1), u * (we - 1))
    x, y = u * we - 0.5, np.clip(v * he - 0.5, 0.0, he - 1)
    x0 = np.floor(x).astype(np.int64)
    fx = (x - x0)[..., None]
    c0, c1 = x0 % we, (x0 + 1) % we
    y0 = np.clip(np.floor(y).astype(np.int64), 0, max(he - 2, 0))
    y1 = np.minimum(y0 + 1, he - 1)
    fy = (y - y0)[..., None]
    top = src[y0, c0] * (1 - fx) + src[y0, c1] * fx
    bottom = src[y1, c0] * (1 - fx) + src[y1, c1] * fx
    return top * (1 - fy) + bottom * fy


def latlong_to_cube(env: EnvironmentMap, face_size: int, *, supersample: int = 2) -> np.ndarray:
    """Resample a lat-long map to an OpenEXR-layout cube map.

    Each cube pixel averages `supersample`² stratified sub-samples of its footprint (uniform
    weights), each a bilinear lookup in `env` (periodic across the seam for centre-aligned maps).

    Args:
        env: the map, in any world-frame convention, "center" or "corner" aligned.
        face_size: N, the face width of the result.
        supersample: sub-samples per cube pixel along each axis (1 = point sampling).

    Returns:
        `[6N, N, 3]` float32 cube-map image (write it with
        `gaffer_envmap.io_exr.write_exr(path, cube, envmap="cube")`).

    Raises:
        ShapeError: bad `face_size` or `supersample`.
        ConventionError: `env` is in a camera-frame convention.

    Example:
        >>> from gaffer_envmap.environment_map import EnvironmentMap
        >>> env = EnvironmentMap(radiance_linear=np.full((4, 8, 3), 2.0, np.float32))
        >>> latlong_to_cube(env, 3).shape
        (18, 3, 3)
    """
    _check_size("face_size", face_size)
    _check_size("supersample", supersample)
    n, s = int(face_size), int(supersample)
    coords = _face_coords(n, _sub_offsets(s)).reshape(-1)  # [N*S]
    b, a = np.meshgrid(coords, coords, indexing="ij")  # [N*S, N*S]
    abc = np.stack([a, b, np.ones_like(a)], axis=-1)
    dirs_exr = np.einsum("fij,rcj->frci", _FACE_MATRIX, abc)  # [6, N*S, N*S, 3]
    dirs = dirs_exr @ _frame_to_openexr(env.convention)  # rows: inverse (orthogonal) map
    u, v = direction_to_uv(dirs, env.convention)
    samples = _sample_latlong(env, np.asarray(u), np.asarray(v))  # [6, N*S, N*S, 3]
    cube = samples.reshape(6, n, s, n, s, 3).mean(axis=(2, 4))
    return cube.reshape(6 * n, n, 3).astype(np.float32)
