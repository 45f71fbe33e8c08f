"""The `EnvironmentMap` value type: linear radiance on a lat-long grid, with its convention named.

Shapes: `radiance_linear` is `[He, We, 3]` float32 with `We == 2 * He`, row 0 = the +up pole,
scene-referred linear Rec.709 RGB (what an EXR holds).
"""

from dataclasses import dataclass, field

import numpy as np

from gaffer_envmap.conventions import PixelAlignment, get_convention
from gaffer_envmap.errors import ShapeError

__all__ = ["EnvironmentMap", "PixelAlignment"]


@dataclass(frozen=True, kw_only=True)
class EnvironmentMap:
    """An equirectangular HDR environment map.

    Attributes:
        radiance_linear: `[He, We, 3]` float32 linear radiance, `We == 2 * He`. Read-only view.
        convention: name of the lat-long convention (see `gaffer_envmap.conventions.CONVENTIONS`),
            "blender" for Blender/Cycles world maps (z up), which is what every gaffer artifact uses.
        alignment: pixel alignment, "center" unless the map came from a corner-aligned source.

    Raises:
        ShapeError: when the array is not `[He, 2*He, 3]`.
        ConventionError: when `convention` is unknown.

    Example:
        >>> import numpy as np
        >>> env = EnvironmentMap(radiance_linear=np.ones((8, 16, 3), np.float32))
        >>> env.height, env.width
        (8, 16)
    """

    radiance_linear: np.ndarray
    convention: str = "blender"
    alignment: PixelAlignment = "center"
    metadata: dict[str, str] = field(default_factory=dict, compare=False)

    def __post_init__(self) -> None:
        arr = np.asarray(self.radiance_linear)
        if arr.ndim != 3 or arr.shape[2] != 3:
            raise ShapeError(
                "radiance_linear",
                arr.shape,
                "[He, We, 3]",
                "Pass an RGB lat-long map (drop alpha with `arr[..., :3]`).",
            )
        he, we = arr.shape[:2]
        if we != 2 * he or he < 1:
            raise ShapeError(
                "radiance_linear",
                arr.shape,
                "[He, 2*He, 3] (a 2:1 equirectangular map)",
                "Crop or resample to 2:1 (e.g. `gaffer_envmap.resize_conservative`) before wrapping it.",
            )
        get_convention(self.convention)
        if self.alignment not in ("center", "corner"):
            raise ShapeError("alignment", self.alignment, "'center' or 'corner'")
        arr = np.ascontiguousarray(arr, dtype=np.float32)
        arr.flags.writeable = False
        object.__setattr__(self, "radiance_linear", arr)

    @property
    def height(self) -> int:
        """He, the number of rows (pole to pole)."""
        return int(self.radiance_linear.shape[0])

    @property
    def width(self) -> int:
        """We, the number of columns (a full turn)."""
        return int(self.radiance_linear.shape[1])

    def with_radiance(self, radiance_linear: np.ndarray) -> "EnvironmentMap":
        """A copy with new pixels and the same convention and alignment."""
        return EnvironmentMap(
            radiance_linear=radiance_linear,
            convention=self.convention,
            alignment=self.alignment,
            metadata=dict(self.metadata),
        )
