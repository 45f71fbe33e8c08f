"""Radiance fields: TensoRF with the vector-matrix decomposition."""

from gaffer_nerf.fields.tensorf import (
    MAT_MODE,
    VEC_MODE,
    AlphaMaskInfo,
    EmptyAlphaMaskWarning,
    FeatureMLP,
    TensoRFVM,
    finite_or_zero,
    log_spaced_voxels,
    positional_encoding,
    voxels_to_grid,
)

__all__ = [
    "MAT_MODE",
    "VEC_MODE",
    "AlphaMaskInfo",
    "EmptyAlphaMaskWarning",
    "FeatureMLP",
    "TensoRFVM",
    "finite_or_zero",
    "log_spaced_voxels",
    "positional_encoding",
    "voxels_to_grid",
]
