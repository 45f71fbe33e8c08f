"""Geometry a photo gives: a learned estimator of camera-frame normals (`estimator`), which feeds the
radiance hints of models with `ModelConfig.hint_geometry == "estimated"` (gaffer-tiny 0.5)."""

from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion.hints import HintGeometry, silhouette_normals

__all__ = ["input_normals"]


def input_normals(
    geometry: HintGeometry,
    image: Float[Tensor, "B 3 H W"],
    mask: Float[Tensor, "B 1 H W"],
) -> Float[Tensor, "B 3 H W"]:
    """The hints' normals of the inputs (display sRGB on white, [0, 1]; their masks): the silhouette
    dome, or the shipped estimator's estimate (`estimator.shipped_normal_estimator`)."""
    if geometry == "silhouette":
        return silhouette_normals(mask)
    from gaffer_diffusion.geometry.estimator import estimate_normals, shipped_normal_estimator

    return estimate_normals(shipped_normal_estimator(), image, mask)
