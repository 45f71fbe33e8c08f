"""Transforms between lat-long conventions that take an `EnvironmentMap`.

They live apart from `conventions` (the uv <-> direction maths, a leaf module) so that
`environment_map` can import `conventions` at the top without an import cycle.
"""

import numpy as np

from gaffer_envmap.conventions import (
    LatLongConvention,
    direction_to_uv,
    get_convention,
    pixel_center_uv,
    uv_to_direction,
)
from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.errors import ConventionError, GafferEnvmapError


def _world_map(src: LatLongConvention, dst: LatLongConvention) -> np.ndarray:
    """3x3 taking dst-world coordinates to src-world coordinates (through Blender's world)."""
    return np.asarray(src.to_blender).T @ np.asarray(dst.to_blender)


def convert_convention(env: EnvironmentMap, dst: str) -> EnvironmentMap:
    """Re-express a map in another convention, exactly (a column roll, plus a flip for mirrored ones).

    Both maps describe the same light in the same physical world (y-up frames related to Blender's by
    (x, y, z) -> (x, z, -y)). Works when the two conventions share their up axis and We is divisible by 4
    (every pair in `CONVENTIONS` differs by quarter turns), so the result is a pure permutation of
    columns: bit-exact and reversible.

    Raises:
        ConventionError: camera-frame conventions (use `rotate_to_camera`), corner-aligned input
            (resample with `to_center_alignment` first), or a shift that is not a whole pixel.
    """
    s, d = get_convention(env.convention), get_convention(dst)
    if "camera" in (s.frame, d.frame) and s.name != d.name:
        raise ConventionError(
            f"`dst` {dst!r}: converting between a world frame and the camera frame needs a pose; "
            "use `gaffer_envmap.rotate_to_camera(env, w2c_blender)`."
        )
    if env.alignment != "center":
        raise ConventionError(
            "`env.alignment` is 'corner'; convert with `gaffer_envmap.to_center_alignment(env)` first."
        )
    m = _world_map(s, d)
    if not np.allclose(m @ np.asarray(d.up, float), np.asarray(s.up, float), atol=1e-12):
        raise ConventionError(
            f"`dst` {dst!r} does not share the up axis of {s.name!r}; use a rotation."
        )
    we = env.width
    # Column j of dst looks at src column j_src = offset + sign*j (both are linear in u).
    u_dst = (np.arange(we) + 0.5) / we
    dirs_src = uv_to_direction(u_dst, np.full(we, 0.5), d.name) @ m.T
    u_src, _ = direction_to_uv(dirs_src, s.name)
    cols = u_src * we - 0.5
    idx = np.rint(cols).astype(np.int64) % we
    err = np.abs(((cols - idx) + we / 2) % we - we / 2)
    if err.max() > 1e-6:
        raise ConventionError(
            f"`env` width {we} does not allow an exact conversion {s.name!r} -> {dst!r} "
            f"(off by {err.max():.3f} px); use a width divisible by 4."
        )
    out = env.radiance_linear[:, idx, :]
    return EnvironmentMap(
        radiance_linear=out, convention=d.name, alignment="center", metadata=dict(env.metadata)
    )


def to_center_alignment(env: EnvironmentMap) -> EnvironmentMap:
    """Resample a corner-aligned map (rows at the poles, seam column duplicated) to pixel-centre alignment.

    Output size: He_out = He - 1 rows (so that row spacing is preserved), We_out = 2 He_out. Linear
    interpolation in u (periodic) and in v; this is a half-pixel resampling and therefore not exact.
    """
    if env.alignment == "center":
        return env
    src = env.radiance_linear.astype(np.float64)
    he_in, we_in = src.shape[:2]
    if he_in < 3:
        raise GafferEnvmapError("`env` is too small to realign (needs at least 3 rows).")
    he = he_in - 1
    we = 2 * he
    u, v = pixel_center_uv(he, we, "center")
    x = u * (we_in - 1)  # corner-aligned: column k at u = k/(We-1); last column == first
    y = v * (he_in - 1)
    x0 = np.clip(np.floor(x).astype(int), 0, we_in - 2)
    y0 = np.clip(np.floor(y).astype(int), 0, he_in - 2)
    fx = (x - x0)[None, :, None]
    fy = (y - y0)[:, None, None]
    rows0, rows1 = src[y0], src[y0 + 1]
    top = rows0[:, x0] * (1 - fx) + rows0[:, x0 + 1] * fx
    bot = rows1[:, x0] * (1 - fx) + rows1[:, x0 + 1] * fx
    out = (top * (1 - fy) + bot * fy).astype(np.float32)
    return EnvironmentMap(
        radiance_linear=out,
        convention=env.convention,
        alignment="center",
        metadata=dict(env.metadata),
    )
