"""The lighting of `relight`: the camera pose (`--w2c`, `--azimuth/--elevation`), the target
environment map(s) or pre-encoded `--ldr/--hdr` maps, their early checks, and the encoded
lighting maps the model is conditioned on."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

from gaffer_diffusion import _cli_checks as checks
from gaffer_diffusion.cli._common import _ENVMAP_SUFFIXES, _compat, _files
from gaffer_diffusion.errors import ConfigError, InputValueError

if TYPE_CHECKING:
    import numpy as np

    from gaffer_diffusion.conditioning import LightingMaps


def _pose(args: argparse.Namespace) -> Any:
    """The camera of `--w2c` or `--azimuth/--elevation`; numpy and gaffer-envmap only (no torch), so
    the checks call it before any weights load."""
    from gaffer_envmap.poses import W2CBlender, orbit_w2c_blender

    if args.w2c is not None:
        if args.azimuth is not None or args.elevation is not None:
            raise ConfigError("Pass either `--w2c` or `--azimuth`/`--elevation`, not both.")
        return W2CBlender.from_array(_read_w2c(args.w2c))
    if args.azimuth is not None and args.elevation is not None:
        checks.finite("--azimuth", args.azimuth)
        checks.finite("--elevation", args.elevation, -90.0, 90.0)
        return orbit_w2c_blender(args.azimuth, args.elevation)
    raise ConfigError("Give the camera: `--w2c W2C.npy`, or both `--azimuth` and `--elevation`.")


def _read_w2c(path: Path) -> np.ndarray:
    """`--w2c`: a 3x4 or 4x4 float .npy (no pickles), refused with one line otherwise."""
    import numpy as np

    checks.need_file("--w2c", path, "a 3x4 or 4x4 world-to-camera .npy (numpy.save)")
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise InputValueError(
            f"`--w2c` {path} is not a plain numeric .npy ({exc}); save the 3x4 or 4x4 matrix with "
            "numpy.save (no pickled objects)."
        ) from exc
    if (
        not isinstance(arr, np.ndarray)
        or arr.dtype.kind not in "fiu"
        or arr.shape not in ((3, 4), (4, 4))
    ):
        shape = getattr(arr, "shape", None)
        raise InputValueError(
            f"`--w2c` {path} holds {getattr(arr, 'dtype', type(arr).__name__)} of shape {shape}; "
            "pass a 3x4 or 4x4 float world-to-camera matrix."
        )
    if not np.isfinite(arr).all():
        raise InputValueError(f"`--w2c` {path} holds NaN or Inf; pass a finite matrix.")
    return arr.astype(np.float64)


def _read_envmap(args: argparse.Namespace, envmap: Path) -> Any:
    """`envmap` read with `--sanitize` (numpy only); a refused map is one line naming the flag."""
    from gaffer_envmap.errors import NonFiniteError
    from gaffer_envmap.io import read_envmap
    from gaffer_envmap.sanitize import sanitize_flag_refusal

    try:
        return read_envmap(envmap, sanitize=args.sanitize)
    except NonFiniteError as exc:
        raise InputValueError(sanitize_flag_refusal(exc, args.sanitize)) from exc


def _envmap_lighting(
    args: argparse.Namespace, envmap: Path, size: int, frames: int = 0
) -> LightingMaps:
    import torch

    from gaffer_diffusion.conditioning import lighting_from_envmap

    pose = _pose(args)
    env = _read_envmap(args, envmap)
    n = max(frames, 1)
    spin = torch.arange(n, dtype=torch.float64) * (360.0 / n) if frames > 1 else 0.0
    return lighting_from_envmap(env, [pose] * n, size=size, compat=_compat(args), spin_deg=spin)


def _lighting(args: argparse.Namespace, size: int, frames: int) -> LightingMaps:
    if args.ldr is not None or args.hdr is not None:
        if args.ldr is None or args.hdr is None or args.envmap is not None:
            raise ConfigError("Pass both `--ldr` and `--hdr` (pre-encoded maps) and no `--envmap`.")
        if frames > 1:
            raise ConfigError("`--turntable` needs `--envmap` (pre-encoded maps cannot be spun).")
        from gaffer_diffusion.conditioning import LightingMaps
        from gaffer_diffusion.evaluation import read_lighting_map

        return LightingMaps(
            ldr=read_lighting_map(args.ldr, size), hdr=read_lighting_map(args.hdr, size)
        )
    if args.envmap is None:
        raise ConfigError(
            "Pass `--envmap ENV.exr` (or `--envmaps DIR`) with a pose, or pre-encoded `--ldr` and "
            "`--hdr` maps."
        )
    return _envmap_lighting(args, args.envmap, size, frames)


def _check_envmap_arg(path: Path) -> None:
    if not path.exists() and not path.suffix:
        from gaffer_envmap.bundled import bundled_hdris

        names = ", ".join(sorted(bundled_hdris()))
        raise InputValueError(
            f"`--envmap` {path} is neither a file nor a bundled HDRI; pass an .exr/.hdr file or one "
            f"of: {names}."
        )
    checks.envmap_file("--envmap", path)


def _check_lighting_args(args: argparse.Namespace) -> None:
    if args.envmaps is not None:
        checks.need_dir("--envmaps", args.envmaps, "a folder of .exr/.hdr maps")
        for m in _files(args.envmaps, _ENVMAP_SUFFIXES, "environment maps", "--envmaps"):
            checks.envmap_file("--envmaps", m)
            _read_envmap(args, m)  # --sanitize's refusal before any weights load
    elif args.ldr is not None or args.hdr is not None:
        if args.ldr is None or args.hdr is None or args.envmap is not None:
            raise ConfigError("Pass both `--ldr` and `--hdr` (pre-encoded maps) and no `--envmap`.")
        if args.turntable > 1:
            raise ConfigError("`--turntable` needs `--envmap` (pre-encoded maps cannot be spun).")
        checks.image_size("--ldr", args.ldr)
        checks.image_size("--hdr", args.hdr)
        return
    elif args.envmap is None:
        raise ConfigError(
            "Pass `--envmap ENV.exr` (or `--envmaps DIR`) with a pose, or pre-encoded `--ldr` and "
            "`--hdr` maps."
        )
    else:
        _check_envmap_arg(args.envmap)
        _read_envmap(args, args.envmap)  # decoded here too: no torch, fails early
    _pose(args)  # reads and checks --w2c, or --azimuth/--elevation (numpy only)
