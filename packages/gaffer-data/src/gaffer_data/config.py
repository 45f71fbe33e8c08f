"""Render configuration: every count, sampling range and Cycles setting of a dataset render.

Defaults follow the Neural Gaffer paper (§3.1) and the authors' Blender 3.2 script: 12 views per object,
16 environment maps per view plus one area-light render, 512x512, 128 samples with the denoiser, diffuse
and glossy bounces 1, transparent and transmission bounces 3, filter width 0.01, a 35 mm lens on a 32 mm
sensor, elevation U(-60, 90) deg, azimuth U(0, 360) deg, distance U(1.5, 2.2), the Filmic view transform.
The whole config is written into every object manifest, so a dataset records how it was made.

This module is pure (no bpy): the reader, the planner and the Blender worker all share it.
"""

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

from gaffer_data.errors import ConfigError
from gaffer_envmap.sanitize import SANITIZE_POLICIES, SanitizePolicy

ViewTransform = Literal["Filmic", "AgX", "Standard", "Khronos PBR Neutral", "Raw"]
"""Blender view transforms that exist in bpy 5.0 (Filmic is the paper's; it was Blender 3.2's default)."""

_VIEW_TRANSFORMS = ("Filmic", "AgX", "Standard", "Khronos PBR Neutral", "Raw")


def _check_range(
    name: str, lo: float | int, hi: float | int, *, min_lo: float | int | None = None
) -> None:
    if not lo <= hi:
        raise ConfigError(
            f"`{name}` is ({lo}, {hi}); the lower bound must not exceed the upper bound."
        )
    if min_lo is not None and lo < min_lo:
        raise ConfigError(f"`{name}` starts at {lo}; it must be >= {min_lo}.")


@dataclass(frozen=True, kw_only=True)
class CameraConfig:
    """Camera intrinsics and the distribution of camera positions (all look at the origin, z up).

    Attributes:
        lens_mm: focal length in millimetres (paper: 35).
        sensor_mm: sensor width in millimetres (paper: 32), giving a horizontal FOV of ~49.1 deg.
        elevation_deg: uniform range of the elevation above the xy plane, in degrees.
        azimuth_deg: uniform range of the azimuth from +x towards +y, in degrees.
        distance: uniform range of the camera distance to the origin (object bbox side is 1).
    """

    lens_mm: float = 35.0
    sensor_mm: float = 32.0
    elevation_deg: tuple[float, float] = (-60.0, 90.0)
    azimuth_deg: tuple[float, float] = (0.0, 360.0)
    distance: tuple[float, float] = (1.5, 2.2)

    def __post_init__(self) -> None:
        if self.lens_mm <= 0 or self.sensor_mm <= 0:
            raise ConfigError(
                f"`lens_mm`={self.lens_mm} and `sensor_mm`={self.sensor_mm} must both be > 0."
            )
        _check_range("elevation_deg", *self.elevation_deg, min_lo=-90.0)
        if self.elevation_deg[1] > 90.0:
            raise ConfigError(f"`elevation_deg` ends at {self.elevation_deg[1]}; it must be <= 90.")
        _check_range("azimuth_deg", *self.azimuth_deg)
        _check_range("distance", *self.distance)
        if self.distance[0] <= 0.0:
            raise ConfigError(
                f"`distance` starts at {self.distance[0]}; cameras need a distance > 0."
            )


@dataclass(frozen=True, kw_only=True)
class AreaLightConfig:
    """The extra render per view under a random area light and a uniform grey world (paper §3.1).

    Attributes:
        energy: uniform range of the light power in watts (authors: U(300, 500)).
        xy: uniform range of the light's x and y position.
        z: uniform range of the light's z position (it points down, -z).
        scale: object scale of the (1 m) square area light (authors: 100).
        world_grey: linear grey level of the world background (authors: 0.35).
    """

    energy: tuple[float, float] = (300.0, 500.0)
    xy: tuple[float, float] = (-1.0, 1.0)
    z: tuple[float, float] = (0.5, 1.5)
    scale: float = 100.0
    world_grey: float = 0.35

    def __post_init__(self) -> None:
        _check_range("area_light.energy", *self.energy, min_lo=0.0)
        _check_range("area_light.xy", *self.xy)
        _check_range("area_light.z", *self.z)
        if self.scale <= 0 or self.world_grey < 0:
            raise ConfigError(
                f"`area_light.scale`={self.scale} must be > 0 and "
                f"`area_light.world_grey`={self.world_grey} must be >= 0."
            )


@dataclass(frozen=True, kw_only=True)
class AugmentConfig:
    """How each environment-map draw is augmented (gaffer-envmap's flip and exact yaw roll).

    Attributes:
        flip: draw a horizontal mirror with probability 1/2.
        yaw_steps: draw a yaw roll of `k / yaw_steps` of a turn, `k` uniform in `[0, yaw_steps)`;
            1 disables the roll. The pool's map widths must be divisible by it.
    """

    flip: bool = True
    yaw_steps: int = 8

    def __post_init__(self) -> None:
        if self.yaw_steps < 1:
            raise ConfigError(f"`augment.yaw_steps`={self.yaw_steps} must be >= 1 (1 = no yaw).")


@dataclass(frozen=True, kw_only=True)
class BounceConfig:
    """Cycles light-path bounce limits (authors: diffuse 1, glossy 1, transparent 3, transmission 3)."""

    max_bounces: int = 12
    diffuse: int = 1
    glossy: int = 1
    transparent: int = 3
    transmission: int = 3

    def __post_init__(self) -> None:
        for name, value in dataclasses.asdict(self).items():
            if value < 0:
                raise ConfigError(f"`bounces.{name}`={value} must be >= 0.")


MultiviewLayout = Literal["sphere", "orbit"]
"""Camera layouts of multi-view sets: a Fibonacci lattice over an elevation band, or one ring."""

if TYPE_CHECKING:
    _LayoutArg = MultiviewLayout
else:  # at run time any str reaches `MultiviewConfig`, whose `__post_init__` refuses an unknown one
    _LayoutArg = str


@dataclass(frozen=True, kw_only=True)
class MultiviewConfig:
    """A multi-view render set for 3D (paper §4.2: 100 train + 20 test poses x 4 lightings; lighting 0
    is the one the radiance field is fitted to, lightings 1.. are the relighting targets).

    Every view of an object is lit by the same `RenderConfig.lightings` environment-map draws (drawn
    once per object, distinct maps while the pool allows), so the views of one lighting form a
    consistent multi-view capture for a radiance field; the cameras look at the origin from a fixed
    distance. Views `0 .. train_views - 1` are the training split, the rest the test split; which lattice
    points are held out is a seeded permutation, so both splits cover the whole layout.

    Attributes:
        train_views: views of the training split.
        test_views: views of the test split.
        layout: "sphere": a Fibonacci lattice, uniform in solid angle over `elevation_deg`;
            "orbit": one ring at `orbit_elevation_deg`, azimuths evenly spaced.
        elevation_deg: elevation band of the sphere layout, in degrees.
        orbit_elevation_deg: elevation of the orbit layout, in degrees.
        distance: camera distance to the origin (object bbox side is 1).
    """

    train_views: int = 100
    test_views: int = 20
    layout: _LayoutArg = "sphere"
    elevation_deg: tuple[float | int, float | int] = (-30.0, 90.0)
    orbit_elevation_deg: float = 30.0
    distance: float = 2.0

    def __post_init__(self) -> None:
        if self.train_views < 1 or self.test_views < 0:
            raise ConfigError(
                f"`multiview.train_views`={self.train_views} must be >= 1 and "
                f"`multiview.test_views`={self.test_views} >= 0."
            )
        if self.layout not in ("sphere", "orbit"):
            raise ConfigError(f"`multiview.layout`={self.layout!r} must be 'sphere' or 'orbit'.")
        _check_range("multiview.elevation_deg", *self.elevation_deg, min_lo=-90.0)
        if self.elevation_deg[1] > 90.0 or not -90.0 <= self.orbit_elevation_deg <= 90.0:
            raise ConfigError(
                f"`multiview.elevation_deg`={self.elevation_deg} and `multiview.orbit_elevation_deg`="
                f"{self.orbit_elevation_deg} must lie in [-90, 90]."
            )
        if not self.distance > 0.0:
            raise ConfigError(f"`multiview.distance`={self.distance} must be > 0.")

    @property
    def views(self) -> int:
        """Total views per object (train + test)."""
        return self.train_views + self.test_views


@dataclass(frozen=True, kw_only=True)
class RenderConfig:
    """Everything that decides what a dataset render produces.

    Attributes:
        views: camera views per object (paper: 12).
        lightings: environment-map renders per view, drawn with replacement from the pool (paper: 16).
        area_light_render: also render each view under a random area light, with normal, albedo and
            depth passes (paper: yes).
        resolution: square image side in pixels (paper: 512).
        samples: Cycles samples per pixel (paper: 128).
        denoise: run the OpenImageDenoise denoiser (paper: yes).
        adaptive_threshold: Cycles adaptive-sampling noise threshold; 0 disables adaptive sampling
            (Blender's default 0.01, as the authors left it).
        filter_width: pixel filter width in pixels (authors: 0.01, i.e. no filtering).
        view_transform: Blender view transform used for the PNGs (paper: Filmic); EXRs are linear.
        envmap_strength: world strength of the environment-map renders (paper: 1).
        envmap_sanitize: NaN/Inf/negative pixels of the pool's maps (CLI `--sanitize`, policies of
            `gaffer_envmap.sanitize`): every map is checked before any render starts, and the
            worker renders the pixels this policy gives. "raise" (default): the tiny negatives of
            lossy compression become 0, anything else refuses the run; "strict" refuses any;
            "zero"/"clamp" repair them.
        background_visible: show the environment map behind the object in the envmap renders (the
            authors do, and mask it later); False renders a transparent film, so the alpha is the mask.
        world_map_resolution: resolution of Cycles' importance map of the environment (affects noise
            only, not the expected image); 0 = Blender's automatic choice, as the authors rendered. A small
            value (e.g. 256) makes small renders several times faster.
        seed: the root seed; each object's cameras and draws come from (seed, object id) only.
        cycles_seed: Cycles' sampling seed (fixed, so re-renders are bit-identical).
        threads: Cycles threads per worker; 0 lets Blender use every core.
        camera: camera intrinsics and pose distribution.
        area_light: area-light render distribution.
        augment: environment-map augmentation.
        bounces: Cycles bounce limits.
        multiview: None for the relighting dataset (per-view random cameras and envmap draws); a
            `MultiviewConfig` for a 3D set (fixed layout, train/test splits, the same lightings for
            every view, `transforms_{train,test}.json`); `views` must then equal its
            `train_views + test_views` (see `multiview_render_config`).

    Example:
        >>> cfg = RenderConfig(views=2, lightings=3, resolution=32, samples=4)
        >>> RenderConfig.from_dict(cfg.to_dict()) == cfg
        True
    """

    views: int = 12
    lightings: int = 16
    area_light_render: bool = True
    resolution: int = 512
    samples: int = 128
    denoise: bool = True
    adaptive_threshold: float = 0.01
    filter_width: float = 0.01
    view_transform: ViewTransform = "Filmic"
    envmap_strength: float = 1.0
    envmap_sanitize: SanitizePolicy = "raise"
    background_visible: bool = False
    world_map_resolution: int = 0
    seed: int = 0
    cycles_seed: int = 0
    threads: int = 0
    camera: CameraConfig = field(default_factory=CameraConfig)
    area_light: AreaLightConfig = field(default_factory=AreaLightConfig)
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    bounces: BounceConfig = field(default_factory=BounceConfig)
    multiview: MultiviewConfig | None = None

    def __post_init__(self) -> None:
        if self.multiview is not None and self.views != self.multiview.views:
            raise ConfigError(
                f"`views`={self.views} must equal `multiview.train_views + multiview.test_views`="
                f"{self.multiview.views}; build the config with `multiview_render_config`."
            )
        for name in ("views", "resolution", "samples"):
            if getattr(self, name) < 1:
                raise ConfigError(f"`{name}`={getattr(self, name)} must be >= 1.")
        if self.lightings < 0 or (self.lightings == 0 and not self.area_light_render):
            raise ConfigError(
                f"`lightings`={self.lightings}: need >= 1 envmap render per view, or 0 with "
                "`area_light_render=True`."
            )
        if self.adaptive_threshold < 0 or self.filter_width <= 0 or self.envmap_strength < 0:
            raise ConfigError(
                f"`adaptive_threshold`={self.adaptive_threshold} must be >= 0, `filter_width`="
                f"{self.filter_width} > 0 and `envmap_strength`={self.envmap_strength} >= 0."
            )
        if self.view_transform not in _VIEW_TRANSFORMS:
            raise ConfigError(
                f"`view_transform`={self.view_transform!r} is not one of {_VIEW_TRANSFORMS}."
            )
        if self.envmap_sanitize not in SANITIZE_POLICIES:
            raise ConfigError(
                f"`envmap_sanitize`={self.envmap_sanitize!r} is not one of {SANITIZE_POLICIES}."
            )
        if self.world_map_resolution < 0:
            raise ConfigError(
                f"`world_map_resolution`={self.world_map_resolution} must be >= 0 (0 = automatic)."
            )
        if self.threads < 0 or self.seed < 0 or self.cycles_seed < 0:
            raise ConfigError(
                f"`threads`={self.threads}, `seed`={self.seed} and `cycles_seed`={self.cycles_seed} "
                "must be >= 0."
            )

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (tuples become lists)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "RenderConfig":
        """Rebuild a config from `to_dict()` output; unknown keys are ignored (newer MINOR versions).

        Raises:
            ConfigError: when a value is out of range or has the wrong type.
        """
        nested = {
            "camera": CameraConfig,
            "area_light": AreaLightConfig,
            "augment": AugmentConfig,
            "bounces": BounceConfig,
            "multiview": MultiviewConfig,
        }
        kwargs: dict[str, Any] = {}
        names = {f.name for f in dataclasses.fields(cls)}
        for key, value in data.items():
            if key not in names:
                continue
            if key in nested and value is not None:
                sub = nested[key]
                sub_names = {f.name for f in dataclasses.fields(sub)}
                sub_kwargs = {
                    k: tuple(v) if isinstance(v, list) else v
                    for k, v in dict(value).items()
                    if k in sub_names
                }
                kwargs[key] = sub(**sub_kwargs)
            else:
                kwargs[key] = value
        try:
            return cls(**kwargs)
        except TypeError as exc:
            raise ConfigError(f"`config` has a malformed field: {exc}") from exc


def multiview_render_config(multiview: MultiviewConfig, **overrides: Any) -> RenderConfig:
    """A `RenderConfig` for a multi-view set: `views` from `multiview`, 4 lightings, no area light.

    Args:
        multiview: the layout and splits.
        **overrides: any other `RenderConfig` field (e.g. `resolution=256`, `lightings=4`).

    Returns:
        The config, with `views = multiview.train_views + multiview.test_views`.

    Raises:
        ConfigError: an override is out of range.

    Example:
        >>> cfg = multiview_render_config(MultiviewConfig(train_views=4, test_views=2), resolution=32)
        >>> cfg.views, cfg.lightings, cfg.area_light_render
        (6, 4, False)
    """
    kwargs: dict[str, Any] = {"lightings": 4, "area_light_render": False, **overrides}
    kwargs["views"] = multiview.views
    kwargs["multiview"] = multiview
    try:
        return RenderConfig(**kwargs)
    except TypeError as exc:
        raise ConfigError(f"`overrides` holds an unknown field: {exc}") from exc
