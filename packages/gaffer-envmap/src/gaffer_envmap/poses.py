"""Camera poses that carry their convention, with explicit converters.

- `W2CBlender`: 3x4 world-to-camera [R | t] with Blender camera axes (x right, y up, the camera looks
  along -z), world z up. This is what the Neural Gaffer authors store per view (`VVV_RT.npy`).
- `C2WOpenCV`: 4x4 camera-to-world with OpenCV camera axes (x right, y down, looks along +z), as
  NeRF/COLMAP-style code expects.

The two camera frames differ by diag(1, -1, -1); converting is exact.
"""

from dataclasses import dataclass

import numpy as np

from gaffer_envmap.errors import PoseError

_BLENDER_TO_OPENCV = np.diag([1.0, -1.0, -1.0])


def check_rotation(rotation: np.ndarray, argument: str, atol: float = 1e-4) -> np.ndarray:
    """Validate a 3x3 rotation (orthonormal, det +1, finite) and return it as float64.

    Raises:
        PoseError: naming `argument`, the defect found, and how to fix it.
    """
    r = np.asarray(rotation, dtype=np.float64)
    if r.shape != (3, 3):
        raise PoseError(f"`{argument}` rotation has shape {r.shape}, expected (3, 3).")
    if not np.all(np.isfinite(r)):
        raise PoseError(f"`{argument}` holds NaN or Inf; pass a finite camera matrix.")
    err = float(np.abs(r @ r.T - np.eye(3)).max())
    if err > atol:
        raise PoseError(
            f"`{argument}` is not a rotation (|R R^T - I| = {err:.2e} > {atol:g}); scale or shear in the "
            "camera matrix? Orthonormalise it (e.g. with an SVD) or pass the world-to-camera matrix itself."
        )
    det = float(np.linalg.det(r))
    if det < 0:
        raise PoseError(
            f"`{argument}` has determinant {det:.3f} (a reflection, not a rotation); check the axis "
            "convention (Blender cameras look along -z, OpenCV along +z)."
        )
    return r


def _as_3x4(matrix: np.ndarray, argument: str) -> np.ndarray:
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape == (4, 4):
        if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-6):
            raise PoseError(
                f"`{argument}` is 4x4 but its last row is {m[3].tolist()}, not [0, 0, 0, 1]."
            )
        m = m[:3]
    if m.shape != (3, 4):
        raise PoseError(f"`{argument}` has shape {m.shape}, expected (3, 4) or (4, 4).")
    check_rotation(m[:, :3], argument)
    if not np.all(np.isfinite(m)):
        raise PoseError(f"`{argument}` holds NaN or Inf.")
    return m


@dataclass(frozen=True)
class W2CBlender:
    """Blender world-to-camera `[3, 4]` float64 (x right, y up, looks along -z; world z up)."""

    matrix: np.ndarray

    def __post_init__(self) -> None:
        m = _as_3x4(self.matrix, "matrix").copy()
        m.flags.writeable = False
        object.__setattr__(self, "matrix", m)

    @classmethod
    def from_array(cls, array: np.ndarray) -> "W2CBlender":
        """From a 3x4 or 4x4 array (e.g. the authors' `VVV_RT.npy`)."""
        return cls(np.asarray(array))

    @property
    def rotation(self) -> np.ndarray:
        """`[3, 3]` world -> Blender-camera rotation."""
        return self.matrix[:, :3]

    @property
    def camera_position_world(self) -> np.ndarray:
        """`[3]` camera centre in world coordinates (-R^T t)."""
        return -self.rotation.T @ self.matrix[:, 3]

    def to_c2w_opencv(self) -> "C2WOpenCV":
        """The same camera as an OpenCV camera-to-world 4x4."""
        r_cv = _BLENDER_TO_OPENCV @ self.rotation  # world -> OpenCV camera
        c2w = np.eye(4)
        c2w[:3, :3] = r_cv.T
        c2w[:3, 3] = self.camera_position_world
        return C2WOpenCV(c2w)


@dataclass(frozen=True)
class C2WOpenCV:
    """OpenCV camera-to-world `[4, 4]` float64 (x right, y down, looks along +z)."""

    matrix: np.ndarray

    def __post_init__(self) -> None:
        m = np.asarray(self.matrix, dtype=np.float64)
        if m.shape != (4, 4):
            raise PoseError(f"`matrix` has shape {m.shape}, expected (4, 4) camera-to-world.")
        if not np.allclose(m[3], [0, 0, 0, 1], atol=1e-6):
            raise PoseError(f"`matrix` last row is {m[3].tolist()}, not [0, 0, 0, 1].")
        check_rotation(m[:3, :3], "matrix")
        m = m.copy()
        m.flags.writeable = False
        object.__setattr__(self, "matrix", m)

    def to_w2c_blender(self) -> W2CBlender:
        """The same camera as a Blender world-to-camera 3x4."""
        r_cv = self.matrix[:3, :3].T  # world -> OpenCV camera
        r_bl: np.ndarray = _BLENDER_TO_OPENCV @ r_cv
        t = np.negative(r_bl @ np.asarray(self.matrix[:3, 3], dtype=np.float64))
        return W2CBlender(np.concatenate([r_bl, t[:, None]], axis=1))


def look_at_w2c_blender(
    camera_position_world: np.ndarray,
    target: tuple[float, float, float] = (0.0, 0.0, 0.0),
    up: tuple[float, float, float] = (0.0, 0.0, 1.0),
) -> W2CBlender:
    """A Blender camera at `camera_position_world` looking at `target`, rolled so world `up` looks up.

    Raises:
        PoseError: when the camera sits on the target or looks straight along `up` (roll undefined).
    """
    eye = np.asarray(camera_position_world, dtype=np.float64)
    forward = np.asarray(target, dtype=np.float64) - eye
    if np.linalg.norm(forward) < 1e-12:
        raise PoseError("`camera_position_world` equals `target`; move the camera away from it.")
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(right) < 1e-9:
        # Looking straight up or down: any roll is valid; pick world +y as the image's up (Blender's
        # track-to constraint does the same kind of choice).
        right = np.cross(forward, np.array([0.0, 1.0, 0.0]))
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, forward)
    rotation = np.stack([right, cam_up, -forward])  # rows: camera x, y, z in world coordinates
    return W2CBlender(np.concatenate([rotation, (-rotation @ eye)[:, None]], axis=1))


def orbit_w2c_blender(
    azimuth_deg: float | int, elevation_deg: float | int, distance: float | int = 1.0
) -> W2CBlender:
    """Camera on a sphere around the origin looking at it (world z up).

    Position = distance * (cos(el) cos(az), cos(el) sin(az), sin(el)); azimuth counter-clockwise from +x
    seen from above, elevation above the horizon.
    """
    if not distance > 0:
        raise PoseError(f"`distance` must be > 0, got {distance}.")
    az, el = np.deg2rad(azimuth_deg), np.deg2rad(elevation_deg)
    eye = distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    # Camera right is horizontal and follows the azimuth, also at el = +-90 degrees, where a generic
    # look-at has no preferred roll; this is the limit Blender's TRACK_TO constraint takes there.
    right = np.array([-np.sin(az), np.cos(az), 0.0])
    forward = -eye / distance
    cam_up = np.cross(right, forward)
    rotation = np.stack([right, cam_up / np.linalg.norm(cam_up), -forward])
    return W2CBlender(np.concatenate([rotation, (-rotation @ eye)[:, None]], axis=1))


IDENTITY_LAYOUT_W2C = W2CBlender(np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0]]))
"""The pose whose camera-frame map equals the Blender world map pixel for pixel: camera right = world +x,
camera up = world +z, looking along world +y (u = 0.25 of both layouts)."""
