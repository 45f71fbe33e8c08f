"""The relighting jobs: every scored lighting, every other bundled HDRI, the turntable's frames."""

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from gaffer_diffusion.conditioning import CompatMode, LightingMaps
from gaffer_diffusion.demo.config import DemoConfig
from gaffer_diffusion.demo.example import _Example
from gaffer_diffusion.demo.turntable import _turntable_hdri
from gaffer_diffusion.errors import DatasetError
from gaffer_diffusion.evaluation import EnvmapLighting
from gaffer_envmap.sanitize import SanitizePolicy


@dataclass(frozen=True, kw_only=True)
class _Lighting:
    """One relighting job: its file stem, label, world-map preview and encoded maps."""

    key: str
    label: str
    kind: Literal["target", "extra", "turntable"]
    world_rgb: np.ndarray | None  # [He, We, 3] uint8 preview, once per map
    maps: LightingMaps  # [1, 3, S, S] E_L and E_H


def _label(lt: EnvmapLighting) -> str:
    parts = [lt.source.stem]
    if lt.flip:
        parts.append("mirrored")
    if lt.yaw_step and lt.num_steps > 1:
        parts.append(f"yaw {lt.yaw_step}/{lt.num_steps} turn")
    if lt.strength != 1.0:
        parts.append(f"strength {lt.strength:g}")
    return ", ".join(parts)


def _preview(env: Any) -> np.ndarray:
    from gaffer_envmap.preview import tonemap_preview

    radiance = np.asarray(env.radiance_linear, np.float32)
    step = max(radiance.shape[0] // 64, 1)  # a 128 x 64 thumbnail is plenty for the report
    return tonemap_preview(radiance[::step, ::step])


class _Envmaps:
    """Each env-map file read once per run, then augmented as the renderer did (cf. `pair_lighting`)."""

    def __init__(self, sanitize: SanitizePolicy = "raise") -> None:
        self._read: dict[Path, Any] = {}
        self._sanitize: SanitizePolicy = sanitize

    def get(self, lt: EnvmapLighting) -> Any:
        from gaffer_envmap import AugmentSpec, EnvironmentMap
        from gaffer_envmap.errors import NonFiniteError
        from gaffer_envmap.io import read_envmap

        if lt.source not in self._read:
            try:
                self._read[lt.source] = read_envmap(lt.source, sanitize=self._sanitize)
            except NonFiniteError as exc:  # said as the flag, not as the API's `sanitize=` hint
                what = str(exc).split(" Pass `sanitize=")[0]
                raise DatasetError(
                    f"{what} Pass `--sanitize zero` (or `clamp`) to repair the map of `--example` "
                    f"(`--sanitize {self._sanitize}` refused it)."
                ) from exc
            except (OSError, ValueError) as exc:
                raise DatasetError(
                    f"Could not read the environment map `{lt.source}` of `--example`: {exc}"
                ) from exc
        spec = AugmentSpec(flip=lt.flip, yaw_step=lt.yaw_step, num_steps=lt.num_steps)
        env = spec.apply(self._read[lt.source])
        if lt.strength != 1.0:
            radiance = np.asarray(env.radiance_linear) * np.float32(lt.strength)
            env = EnvironmentMap(radiance_linear=radiance)
        return env


def _lightings(
    example: _Example, config: DemoConfig, size: int, compat: CompatMode
) -> list[_Lighting]:
    from gaffer_diffusion.conditioning import lighting_from_envmap
    from gaffer_envmap.bundled import bundled_hdris, read_bundled_hdri

    envmaps = _Envmaps(config.sanitize)
    w2c = torch.tensor(example.w2c_blender[None])  # [1, 3, 4], the input view's camera
    jobs: list[_Lighting] = []
    for p in example.pairs:
        lt = p.lighting
        if not isinstance(lt, EnvmapLighting):  # checked in _read_example
            raise DatasetError(f"`{p.name}` has no environment map.")
        env = envmaps.get(lt)
        # Neural Gaffer §3.2: the target map rotated into the input camera's frame, then E_L / E_H
        m = lighting_from_envmap(env, w2c, size=size, compat=compat)
        key = f"{p.target_lighting:03d}_{lt.source.stem}"
        jobs.append(
            _Lighting(key=key, label=_label(lt), kind="target", world_rgb=_preview(env), maps=m)
        )
    if config.extra_hdris:
        scored = {p.lighting.source.stem for p in example.pairs}  # type: ignore[union-attr]
        for name in sorted(set(bundled_hdris()) - scored):
            env = read_bundled_hdri(name)
            m = lighting_from_envmap(env, w2c, size=size, compat=compat)
            jobs.append(
                _Lighting(
                    key=f"extra_{name}", label=name, kind="extra", world_rgb=_preview(env), maps=m
                )
            )
    if config.frames:
        name, env = _turntable_hdri(config.turntable_hdri)
        n = config.frames
        spin = torch.arange(n, dtype=torch.float64) * (360.0 / n)
        m = lighting_from_envmap(
            env, w2c.expand(n, -1, -1), size=size, compat=compat, spin_deg=spin
        )
        for k in range(n):
            jobs.append(
                _Lighting(
                    key=f"frame_{k:03d}",
                    label=f"{name}, spun {float(spin[k]):.0f} deg about world up",
                    kind="turntable",
                    world_rgb=None,
                    maps=LightingMaps(ldr=m.ldr[k : k + 1], hdr=m.hdr[k : k + 1]),
                )
            )
    return jobs
