"""Typed, frozen configs for fitting and relighting a radiance field, with the paper's defaults.

The defaults are the authors' 3D setup (official implementation §6; paper §4.1 "3D relighting"):
TensoRF VM with density ranks 16x3 and appearance ranks 48x3, `MLP_Fea` shading (view PE 2, feature PE 2),
softplus density, 30K iterations of 4096 rays, grid 128^3 -> 300^3 voxels (upsampled at 2000, 3000,
4000, 5500, 7000), alpha-mask updates at 2000 and 4000, L1 weight 8e-5 then 4e-5, bbox +-1.4, near/far
0.2-3.2, white background; Stage 1: 2,500 iterations of 4096 rays, grid lr 0.02, network lr 1e-3, Adam
(0.9, 0.99); Stage 2: 500 iterations, t* 0.4 -> 0.05 (exponential), loss 0.5 L1 + 0.5 perceptual, learning
rates x 0.1^(1/200) per step.

`fit_preset("tiny")` / `relight_preset("tiny")` are CPU-sized versions for tests and demos.
"""

import math
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Literal, assert_never, get_args

from gaffer_nerf.errors import ConfigError

if TYPE_CHECKING:
    from gaffer_diffusion import DefaultSampling

Ranks = tuple[int, int, int]

SizingMode = Literal["fixed", "footprint"]
"""How the final grid resolution is chosen: the paper's fixed voxel count, or from the pixel footprint."""

TStarSchedule = Literal["exponential", "authors"]
"""Stage-2 noise level t*: the paper's exponential decay, or the authors' effectively constant one."""

TargetDetail = Literal["model", "transfer"]
"""Stage-1 targets: the relit views as the model made them (paper), or the model's change of shading
applied to the input views (their texture kept; `gaffer_nerf.relight.detail`)."""

Stage2Loss = Literal["guidance", "sds"]
"""Stage-2 objective: the paper's diffusion guidance loss (Eq. 3) or score distillation (baseline)."""

Ablation = Literal["full", "no-stage1", "no-stage2", "sds-stage2", "sds-only"]
"""Paper §4.4 ablations: the full pipeline, without Stage 1, without Stage 2, SDS instead of the guidance
loss in Stage 2, and the SDS baseline (SDS on the input radiance field, no Stage 1)."""

PresetName = Literal["paper", "tiny"]

ABLATIONS: tuple[Ablation, ...] = ("full", "no-stage1", "no-stage2", "sds-stage2", "sds-only")

if TYPE_CHECKING:
    _Stage2LossArg = Stage2Loss
    _AblationArg = Ablation
else:  # at run time any str reaches `Stage2Config` / `with_ablation`, which refuse an unknown one
    _Stage2LossArg = _AblationArg = str  # with a ConfigError, also under the test-time type hook


def _positive(name: str, value: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
        raise ConfigError(f"`{name}` is {value!r}; expected a finite value > 0.")


def _non_negative(name: str, value: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
        raise ConfigError(f"`{name}` is {value!r}; expected a finite value >= 0.")


def _ranks(name: str, value: Ranks) -> None:
    if len(value) != 3 or any(int(r) < 1 for r in value):
        raise ConfigError(f"`{name}` is {value!r}; expected three ranks >= 1 (one per plane/line).")


@dataclass(frozen=True, kw_only=True)
class SceneBoxConfig:
    """Where the object is and how rays are bounded.

    Attributes:
        aabb_min: world-space corner of the initial bounding box (authors: -1.4 on each axis).
        aabb_max: opposite corner (authors: +1.4).
        near: closest ray distance (0.2).
        far: farthest ray distance (3.2).
        white_background: composite renders over white (the authors' and NeRF-Synthetic's choice).
    """

    aabb_min: tuple[float | int, float | int, float | int] = (-1.4, -1.4, -1.4)
    aabb_max: tuple[float | int, float | int, float | int] = (1.4, 1.4, 1.4)
    near: float = 0.2
    far: float = 3.2
    white_background: bool = True

    def __post_init__(self) -> None:
        if any(not hi > lo for lo, hi in zip(self.aabb_min, self.aabb_max, strict=True)):
            raise ConfigError(
                f"`aabb_min` {self.aabb_min} must be below `aabb_max` {self.aabb_max} on every axis."
            )
        if not 0 <= self.near < self.far:
            raise ConfigError(f"`near`={self.near} and `far`={self.far}: need 0 <= near < far.")


@dataclass(frozen=True, kw_only=True)
class TensoRFConfig:
    """Shape of the TensoRF VM field (Chen et al. 2022) and of its ray marcher.

    Attributes:
        density_ranks: components per plane/line pair of the density tensor (16, 16, 16).
        appearance_ranks: components of the appearance tensor (48, 48, 48).
        appearance_dim: width of the appearance feature fed to the shading MLP (27).
        mlp_hidden: hidden width of `MLP_Fea` (128).
        view_pe: positional-encoding frequencies of the view direction (2).
        feature_pe: positional-encoding frequencies of the appearance feature (2).
        density_shift: added before the softplus (-10), so an untrained field is nearly empty.
        distance_scale: scale of the sample spacing in alpha = 1 - exp(-sigma * delta * scale) (25).
        step_ratio: ray-march step as a fraction of the mean voxel size (0.5).
        weight_threshold: samples with a smaller rendering weight skip the appearance network (1e-4).
        alpha_mask_threshold: voxels whose alpha (after a 3x3x3 max-pool) falls below are empty (1e-4).
        init_scale: standard deviation of the random factor initialisation (0.1).
        max_samples: cap on samples per ray (TensoRF: 1e6, i.e. set by the grid).
    """

    density_ranks: Ranks = (16, 16, 16)
    appearance_ranks: Ranks = (48, 48, 48)
    appearance_dim: int = 27
    mlp_hidden: int = 128
    view_pe: int = 2
    feature_pe: int = 2
    density_shift: float = -10.0
    distance_scale: float = 25.0
    step_ratio: float = 0.5
    weight_threshold: float = 1e-4
    alpha_mask_threshold: float = 1e-4
    init_scale: float = 0.1
    max_samples: int = 1_000_000

    def __post_init__(self) -> None:
        _ranks("density_ranks", self.density_ranks)
        _ranks("appearance_ranks", self.appearance_ranks)
        for name in ("appearance_dim", "mlp_hidden", "max_samples"):
            if int(getattr(self, name)) < 1:
                raise ConfigError(f"`{name}` is {getattr(self, name)!r}; expected >= 1.")
        for name in ("view_pe", "feature_pe"):
            if int(getattr(self, name)) < 0:
                raise ConfigError(f"`{name}` is {getattr(self, name)!r}; expected >= 0.")
        for name in ("distance_scale", "step_ratio", "init_scale"):
            _positive(name, getattr(self, name))
        for name in ("weight_threshold", "alpha_mask_threshold"):
            _non_negative(name, getattr(self, name))


PAPER_RAYS_PER_CELL = 30_000 * 4096 / 300**2
"""Rays per cell of a factor plane in the paper's fit: 30K iterations x 4096 rays on 300^2 (~1365)."""

RAYS_PER_CELL = 768.0
"""`GridSizingConfig.rays_per_cell`'s default: 300 x 1024 rays on 20^2, the side where the fixed-grid
PSNR curve of `benchmarks/bench_nerf_sizing.py` peaks (flat over 16-24; 12 and 32 lose 1-2 dB) for
that budget. The paper's ratio (`PAPER_RAYS_PER_CELL`) picks 15^3 there, 1 dB below. At 768 the
paper's schedule allows 400 > its 300 cap, so the paper's fit keeps 300^3. Calibrated on one synthetic
scene: a starting point, not a law. On gaffer-data renders of unseen objects
(`bench_nerf_sizing.py --real`) its 20^3 is the best fixed grid's PSNR within 0.02 dB on the validation
split but 0.55 dB below 16^3 on the test split (one object of three)."""


@dataclass(frozen=True, kw_only=True)
class GridSizingConfig:
    """How fine the final grid is ("model no more than the scene needs").

    Attributes:
        mode: "fixed": `FitConfig.final_voxels` over the (shrunk) box, as the paper (300^3);
            "footprint": voxel size = the finest camera's pixel footprint at the object's depth divided
            by `oversample`, so a 256 px capture never gets more voxels than its pixels can constrain.
            The iteration budget caps it too (`rays_per_cell`).
        oversample: voxels per pixel footprint along one axis (1.0).
        max_resolution: cap on voxels per axis (300, the paper's).
        min_resolution: floor on voxels per axis (16).
        rays_per_cell: "footprint" mode only: the fit's budget of `iterations x batch_rays` rays must
            give each cell of an R x R factor plane at least this many rays, so the grid holds at
            most R^3 voxels with R = sqrt(iterations x batch_rays / rays_per_cell): cells a short fit
            cannot train only slow it down and cost PSNR. Default `RAYS_PER_CELL` (768: the tiny
            preset's 300 x 1024 rays give 20^3, the paper's 30K x 4096 more than its 300^3 cap).
            None: no budget cap (the footprint alone).
    """

    mode: SizingMode = "fixed"
    oversample: float = 1.0
    max_resolution: int = 300
    min_resolution: int = 16
    rays_per_cell: float | None = RAYS_PER_CELL

    def __post_init__(self) -> None:
        if self.mode not in ("fixed", "footprint"):
            raise ConfigError(f"`mode` is {self.mode!r}; expected 'fixed' or 'footprint'.")
        _positive("oversample", self.oversample)
        if self.rays_per_cell is not None:
            _positive("rays_per_cell", self.rays_per_cell)
        if not 2 <= self.min_resolution <= self.max_resolution:
            raise ConfigError(
                f"`min_resolution`={self.min_resolution}, `max_resolution`={self.max_resolution}: "
                "need 2 <= min <= max."
            )


@dataclass(frozen=True, kw_only=True)
class EarlyStoppingConfig:
    """Stop fitting when the held-out PSNR stops improving.

    Attributes:
        eval_every: iterations between held-out evaluations.
        patience: evaluations without an improvement of `min_delta_db` before stopping.
        min_delta_db: smallest PSNR gain that counts as an improvement, in dB.
        max_rays: held-out rays scored per evaluation (a fixed, seeded subset).
        min_iterations: never stop before this many iterations (the grid must have been upsampled).
    """

    eval_every: int = 1000
    patience: int = 3
    min_delta_db: float = 0.05
    max_rays: int = 16384
    min_iterations: int = 8000

    def __post_init__(self) -> None:
        if self.eval_every < 1 or self.patience < 1 or self.max_rays < 1:
            raise ConfigError(
                f"`eval_every`={self.eval_every}, `patience`={self.patience}, `max_rays`="
                f"{self.max_rays}: all must be >= 1."
            )
        _non_negative("min_delta_db", self.min_delta_db)


@dataclass(frozen=True, kw_only=True)
class RankSelectionConfig:
    """Choose the VM ranks from held-out PSNR ("ranks ... stopped when held-out PSNR stops improving").

    The field is fitted once per rung of `ladder`, smallest first: rung k multiplies
    `TensoRFConfig.density_ranks` and `appearance_ranks` by `ladder[k]` (rounded, at least 1; rungs
    that round to the same ranks are fitted once). The climb stops at the first rung whose held-out
    PSNR is within `tolerance_db` of the next larger rung's, and keeps that smaller rung; it keeps the
    largest rung when every step up gains more than `tolerance_db`. Choosing rung k costs k + 2 fits
    (k + 1 when k is the last), each with the full `FitConfig` (early stopping included).

    Attributes:
        ladder: strictly increasing rank multipliers, (0.25, 0.5, 1.0): with the paper's ranks,
            density 4/8/16 and appearance 12/24/48 per plane/line pair.
        tolerance_db: a larger rung must beat the smaller one by more than this to be worth it (0.25).
        max_rays: held-out rays scored per rung (a fixed, seeded subset).

    Example:
        >>> RankSelectionConfig().scaled_ranks((16, 16, 16), 0.25)
        (4, 4, 4)
    """

    ladder: tuple[float, ...] = (0.25, 0.5, 1.0)
    tolerance_db: float = 0.25
    max_rays: int = 16384

    def __post_init__(self) -> None:
        if not self.ladder:
            raise ConfigError(
                "`ladder` is empty; give at least one rank multiplier, e.g. (0.5, 1.0)."
            )
        for s in self.ladder:
            _positive("ladder", s)
        if list(self.ladder) != sorted(set(self.ladder)):
            raise ConfigError(f"`ladder` {self.ladder} must be strictly increasing (small first).")
        _non_negative("tolerance_db", self.tolerance_db)
        if self.max_rays < 1:
            raise ConfigError(f"`max_rays` is {self.max_rays!r}; expected >= 1.")

    @staticmethod
    def scaled_ranks(ranks: Ranks, scale: float) -> Ranks:
        """`ranks` times `scale`, rounded, at least 1 each."""
        a, b, c = (max(1, round(r * scale)) for r in ranks)
        return (a, b, c)


@dataclass(frozen=True, kw_only=True)
class FitConfig:
    """Fitting the radiance field to the input-lighting images (official implementation §6).

    Attributes:
        tensorf: the TensoRF shape.
        scene: bounding box, near/far, background.
        iterations: optimisation steps (30,000).
        batch_rays: rays per step (4096).
        initial_voxels: voxels of the initial grid (128^3).
        final_voxels: voxels after the last upsampling when `sizing.mode == "fixed"` (300^3).
        upsample_at: iterations at which the grid is upsampled (log-spaced voxel counts).
        alpha_mask_at: iterations at which the alpha mask is rebuilt; the first one shrinks the box.
        lr_grid: Adam learning rate of the factor grids (0.02).
        lr_network: Adam learning rate of the basis matrix and the MLP (1e-3).
        lr_decay_ratio: learning rates decay exponentially to this fraction over `iterations` (0.1).
        betas: Adam betas (0.9, 0.99).
        l1_weight_initial: L1 weight on the density factors before the first alpha mask (8e-5).
        l1_weight_rest: afterwards (4e-5).
        tv_weight_density: total-variation weight on the density planes (0 for synthetic scenes).
        tv_weight_appearance: total-variation weight on the appearance planes (0).
        sizing: how fine the final grid is.
        early_stopping: stop on a held-out PSNR plateau; None runs every iteration.
        seed: torch seed for initialisation and ray sampling.
        rank_selection: fit a ladder of VM ranks and keep the smallest that the held-out PSNR
            justifies; None fits `tensorf`'s ranks once (the paper).
    """

    tensorf: TensoRFConfig = field(default_factory=TensoRFConfig)
    scene: SceneBoxConfig = field(default_factory=SceneBoxConfig)
    iterations: int = 30_000
    batch_rays: int = 4096
    initial_voxels: int = 128**3
    final_voxels: int = 300**3
    upsample_at: tuple[int, ...] = (2000, 3000, 4000, 5500, 7000)
    alpha_mask_at: tuple[int, ...] = (2000, 4000)
    lr_grid: float = 0.02
    lr_network: float = 1e-3
    lr_decay_ratio: float = 0.1
    betas: tuple[float, float] = (0.9, 0.99)
    l1_weight_initial: float = 8e-5
    l1_weight_rest: float = 4e-5
    tv_weight_density: float = 0.0
    tv_weight_appearance: float = 0.0
    sizing: GridSizingConfig = field(default_factory=GridSizingConfig)
    early_stopping: EarlyStoppingConfig | None = None
    seed: int = 0
    rank_selection: RankSelectionConfig | None = None

    def __post_init__(self) -> None:
        if self.iterations < 1 or self.batch_rays < 1:
            raise ConfigError(
                f"`iterations`={self.iterations} and `batch_rays`={self.batch_rays} must be >= 1."
            )
        if self.initial_voxels < 8 or self.final_voxels < self.initial_voxels:
            raise ConfigError(
                f"`initial_voxels`={self.initial_voxels}, `final_voxels`={self.final_voxels}: need "
                "8 <= initial <= final."
            )
        if list(self.upsample_at) != sorted(set(self.upsample_at)):
            raise ConfigError(f"`upsample_at` {self.upsample_at} must be strictly increasing.")
        if list(self.alpha_mask_at) != sorted(set(self.alpha_mask_at)):
            raise ConfigError(f"`alpha_mask_at` {self.alpha_mask_at} must be strictly increasing.")
        for name in ("lr_grid", "lr_network", "lr_decay_ratio"):
            _positive(name, getattr(self, name))
        for name in (
            "l1_weight_initial",
            "l1_weight_rest",
            "tv_weight_density",
            "tv_weight_appearance",
        ):
            _non_negative(name, getattr(self, name))
        if not all(0 <= b < 1 for b in self.betas):
            raise ConfigError(f"`betas` {self.betas} must lie in [0, 1).")


CompatName = Literal["neural-gaffer", "default"]
"""gaffer-envmap lighting encoding: the released checkpoint's ("neural-gaffer") or gaffer-envmap's."""

SamplerName = Literal["ddim", "dpmpp-2m", "unipc"]
"""The samplers the relighting stages offer (`--scheduler`; gaffer-diffusion's `SamplingConfig.scheduler`,
named here too so that the CLI checks them before torch loads): the paper's DDIM, or DPM-Solver++ (2M)
and UniPC, second-order multistep solvers for 15-25 steps (`benchmarks/results/cpu_fast.json`)."""

SAMPLERS: tuple[SamplerName, ...] = get_args(SamplerName)

MULTISTEP_SAMPLERS: tuple[SamplerName, ...] = ("dpmpp-2m", "unipc")
"""Samplers that reuse earlier steps' predictions: they need 2 steps or more."""

SAMPLER_LABELS: dict[SamplerName, str] = {
    "ddim": "DDIM",
    "dpmpp-2m": "DPM-Solver++",
    "unipc": "UniPC",
}
"""How the command line names each sampler in its output line."""


@dataclass(frozen=True, kw_only=True)
class DiffusionSamplingConfig:
    """How the diffusion model is called from the relighting stages (official implementation §2).

    None means "the model's own" (`RelightPipeline.default_sampling`, read from its folder once;
    gaffer-tiny: 1 step, guidance 1, mirror average, "default" encoding; a model without one: the
    paper's 50 steps, guidance 3); `resolved` overrides it with the values given.

    Attributes:
        num_inference_steps: sampler steps of the full schedule; Stage 2 runs the ones below t*.
        scheduler: the sampler of Stage 1's relit views and Stage 2's targets: "ddim" (the paper's;
            None means it), or "dpmpp-2m" / "unipc" at fewer steps (Stage 1 of the paper-size model
            on a CPU: `benchmarks/results/cpu_fast.json`). Multistep solvers need 2 steps or more.
        guidance_scale: classifier-free guidance scale.
        average_samples: samples averaged per relit view / guidance target.
        mirror_average: also relight the mirrored view under the mirrored lighting, flip back and
            average (Stage 1 targets, Stage 2 targets and the SDS gradient).
        latent_mode: conditioning latents from the VAE posterior "mode" or a "sample".
        batch_size: views relit per pipeline call in Stage 1.
        compat: lighting encoding, "neural-gaffer" for the released checkpoint or "default".
        seed: base seed.
        shared_noise: every view of Stage 1 starts from the same initial noise (seed `seed`, and
            the same posterior noise with `latent_mode="sample"`), so the relit views differ only
            where their inputs and lightings do. False (default): view i uses seed `seed + i`.
            Measured (`benchmarks/bench_nerf.py`, gaffer-tiny 0.4 on the sphere scene,
            16-frame closed orbit, one run): shared noise cuts the relit views' flicker by 31%
            (`gaffer_nerf.flicker`, 0.064 -> 0.044) but costs 0.8 dB, and the Stage-1 field fitted to
            them flickers 3% less and scores 0.64 dB lower: the field averages independent per-view
            noise away and bakes in noise shared by every view. On real renders it goes the other
            way: on the validation split (`python benchmarks/nerf_sweep.py run noise`: 3 unseen objects,
            full method, gaffer-tiny) shared noise scored +0.88 dB object PSNR (5/6 pairs) and
            ST-LPIPS 0.205 vs 0.220. At gaffer-tiny's own 128 px (the CLI defaults' validation,
            `benchmarks/bench_nerf_cli_defaults.py --validation`) shared noise lost on every object
            again, as on the sphere, so `relight_preset("tiny")` no longer sets it.
        object_fraction: how each view is shown to the model: a fraction f crops the object-centred
            square in which its longer side spans f (`gaffer_nerf.guidance.framing`), "whole" resizes
            the whole view (the paper), None the model's own framing (gaffer-tiny: 0.75, the crops it
            was trained on; a model without one: "whole").
    """

    num_inference_steps: int | None = None
    scheduler: SamplerName | None = None
    guidance_scale: float | None = None
    average_samples: int | None = None
    mirror_average: bool | None = None
    latent_mode: Literal["mode", "sample"] | None = None
    batch_size: int = 8
    compat: CompatName | None = None
    seed: int = 0
    shared_noise: bool = False
    object_fraction: float | Literal["whole"] | None = None

    def __post_init__(self) -> None:
        f = self.object_fraction
        if (
            f is not None
            and f != "whole"
            and not (
                isinstance(f, int | float)
                and not isinstance(f, bool)
                and math.isfinite(f)
                and 0.0 < f <= 1.0
            )
        ):
            raise ConfigError(
                f"`object_fraction` (--object-fraction) is {f!r}; expected a fraction in (0, 1] "
                "(gaffer-tiny: 0.75) or 'whole' (show the model whole views, the paper)."
            )
        if not isinstance(self.shared_noise, bool):
            raise ConfigError(
                f"`shared_noise` (--[no-]shared-noise) is {self.shared_noise!r}; expected a bool."
            )
        steps = self.num_inference_steps
        if steps is not None and not (isinstance(steps, int) and 1 <= steps <= 1000):
            raise ConfigError(
                f"`num_inference_steps` (--steps) is {steps!r}; expected an int in [1, 1000]."
            )
        if self.scheduler is not None and self.scheduler not in SAMPLERS:
            raise ConfigError(
                f"`scheduler` (--scheduler) is {self.scheduler!r}; expected one of "
                f"{', '.join(SAMPLERS)} (the paper: ddim)."
            )
        _check_multistep_steps(self.scheduler, steps)
        if not isinstance(self.batch_size, int) or self.batch_size < 1:
            raise ConfigError(f"`batch_size` is {self.batch_size!r}; expected an int >= 1.")
        g = self.guidance_scale
        if g is not None and not (isinstance(g, int | float) and math.isfinite(g) and g >= 0):
            raise ConfigError(
                f"`guidance_scale` (--guidance) is {g!r}; expected a finite value >= 0 (paper: 3)."
            )
        avg = self.average_samples
        if avg is not None and not (isinstance(avg, int) and avg >= 1):
            raise ConfigError(
                f"`average_samples` (--average-samples) is {avg!r}; expected an int >= 1."
            )
        if self.compat is not None and self.compat not in ("neural-gaffer", "default"):
            raise ConfigError(
                f"`compat` (--compat) is {self.compat!r}; expected 'neural-gaffer' or 'default'."
            )
        if self.latent_mode is not None and self.latent_mode not in ("mode", "sample"):
            raise ConfigError(
                f"`latent_mode` (--latent-mode) is {self.latent_mode!r}; expected 'mode' or 'sample'."
            )

    def resolved(self, default: "DefaultSampling") -> "DiffusionSamplingConfig":
        """This config with every None replaced by the model's own sampling (`default`, a
        pipeline's `default_sampling`); an explicit encoding brings its latent mode
        (`gaffer_diffusion.latent_mode_for`, the rule `gaffer-diffusion relight` follows).

        Example:
            >>> from gaffer_diffusion import PAPER_SAMPLING
            >>> DiffusionSamplingConfig(guidance_scale=2.0).resolved(PAPER_SAMPLING).num_inference_steps
            50
        """
        own = default.override(
            num_inference_steps=self.num_inference_steps,
            guidance_scale=self.guidance_scale,
            average_samples=self.average_samples,
            mirror_average=self.mirror_average,
            compat=self.compat,
        )
        fraction = own.object_fraction
        # the model's own steps (gaffer-tiny: 1) may be too few for a multistep solver asked for
        _check_multistep_steps(self.scheduler, own.num_inference_steps)
        return replace(
            self,
            num_inference_steps=own.num_inference_steps,
            scheduler=self.scheduler or "ddim",
            guidance_scale=float(own.guidance_scale),
            average_samples=own.average_samples,
            mirror_average=bool(own.mirror_average),
            latent_mode=self.latent_mode or own.latent_mode,
            compat=own.compat,
            object_fraction=self.object_fraction
            or ("whole" if fraction is None else float(fraction)),
        )

    @property
    def crop_fraction(self) -> float | None:
        """The object fraction views are cropped to, None for whole views (resolved configs only)."""
        f = self.object_fraction
        return None if f is None or f == "whole" else float(f)


def _check_multistep_steps(scheduler: SamplerName | None, steps: int | None) -> None:
    """A multistep solver with fewer than 2 steps is refused, naming both flags."""
    if scheduler in MULTISTEP_SAMPLERS and steps is not None and steps < 2:
        raise ConfigError(
            f"`scheduler` (--scheduler) {scheduler!r} with {steps} step: a multistep solver needs "
            "2 steps or more (15-25 is its range); pass `--steps 20`, or `--scheduler ddim`."
        )


def _check_target_detail(target_detail: str, transfer_radius_px: int) -> None:
    """The Stage-1 / Stage-2 targets' detail setting (`TargetDetail` and its box radius)."""
    if target_detail not in ("model", "transfer"):
        raise ConfigError(f"`target_detail`={target_detail!r} must be 'model' or 'transfer'.")
    if transfer_radius_px < 0:
        raise ConfigError(f"`transfer_radius_px`={transfer_radius_px} must be >= 0 (0: per pixel).")


@dataclass(frozen=True, kw_only=True)
class Stage1Config:
    """Stage 1: fit the appearance to the diffusion-relit training views with L2 (paper Eq. 2).

    Attributes:
        iterations: steps (2,500).
        batch_rays: random rays per step (4096).
        lr_grid: appearance planes/lines (0.02).
        lr_network: basis matrix and MLP (1e-3).
        lr_decay_ratio: exponential decay of both over the stage (1.0: constant; the reference lists
            no decay for this stage).
        betas: Adam betas (0.9, 0.99).
        target_detail: "model" (the paper: fit the relit views as the model made them) or
            "transfer" (fit the input views times the model's change of shading, smoothed over
            `transfer_radius_px`: the input's texture survives a model that blurs it;
            `gaffer_nerf.relight.detail.transfer_shading`).
        transfer_radius_px: half-width, in view pixels, of the box the log shading ratio is
            averaged over ("transfer" only; 0: the ratio pixel by pixel).
    """

    iterations: int = 2500
    batch_rays: int = 4096
    lr_grid: float = 0.02
    lr_network: float = 1e-3
    lr_decay_ratio: float = 1.0
    betas: tuple[float, float] = (0.9, 0.99)
    target_detail: TargetDetail = "model"
    transfer_radius_px: int = 2

    def __post_init__(self) -> None:
        if self.iterations < 1 or self.batch_rays < 1:
            raise ConfigError(
                f"`iterations`={self.iterations} and `batch_rays`={self.batch_rays} must be >= 1."
            )
        _check_target_detail(self.target_detail, self.transfer_radius_px)
        for name in ("lr_grid", "lr_network", "lr_decay_ratio"):
            _positive(name, getattr(self, name))


@dataclass(frozen=True, kw_only=True)
class Stage2Config:
    """Stage 2: refine the appearance with the diffusion guidance loss (paper Eq. 3) or SDS.

    Attributes:
        iterations: steps, one full training view each (500).
        loss: "guidance" (paper) or "sds" (the baseline the paper rejects).
        t_start: t* at the first step, as a fraction of the 1000 training timesteps (0.4).
        t_end: t* at the last step (0.05).
        t_schedule: "exponential" (paper: t* = t_start (t_end / t_start)^(k / (K - 1))) or "authors"
            (the shape of the authors' code: 0.38-0.40 for all but the last few steps).
        l1_weight: w1 (0.5).
        perceptual_weight: w2 (0.5).
        image_tv_weight: weight of an image total-variation term the authors' code adds (1.0 there)
            but the paper does not mention (0.0 here).
        lr_grid: appearance planes/lines (0.02).
        lr_network: basis matrix and MLP (1e-3).
        lr_gamma: every step multiplies all learning rates by this (0.1^(1/200)).
        betas: Adam betas (0.9, 0.99).
        sds_t_range: SDS timesteps are drawn uniformly from this fraction range (0.02, 0.98).
        sds_guidance_scale: CFG scale of the SDS baseline; None: the model's own guidance scale
            (`DiffusionSamplingConfig.guidance_scale`, the paper's 3 for the released checkpoint).
        sds_weight: scale of the SDS gradient (1.0).
        encode_mode: VAE posterior "mode" (deterministic) or "sample" for the rendered view.
        target_detail: "guidance" loss only: "model" (the paper: the render is pulled toward the
            model's denoised view) or "transfer" (toward the render times the model's change of
            shading, averaged over `transfer_radius_px`: the render's texture is not pulled toward
            the model's blur; `gaffer_nerf.relight.detail.transfer_shading`).
        transfer_radius_px: box half-width in the model's pixels ("transfer" only).
    """

    iterations: int = 500
    loss: _Stage2LossArg = "guidance"
    t_start: float = 0.4
    t_end: float = 0.05
    t_schedule: TStarSchedule = "exponential"
    l1_weight: float = 0.5
    perceptual_weight: float = 0.5
    image_tv_weight: float = 0.0
    lr_grid: float = 0.02
    lr_network: float = 1e-3
    lr_gamma: float = 0.1 ** (1.0 / 200.0)
    betas: tuple[float, float] = (0.9, 0.99)
    sds_t_range: tuple[float, float] = (0.02, 0.98)
    sds_guidance_scale: float | None = None
    sds_weight: float = 1.0
    encode_mode: Literal["mode", "sample"] = "mode"
    target_detail: TargetDetail = "model"
    transfer_radius_px: int = 8

    def __post_init__(self) -> None:
        if self.iterations < 1:
            raise ConfigError(f"`iterations`={self.iterations} must be >= 1.")
        _check_target_detail(self.target_detail, self.transfer_radius_px)
        if self.loss not in ("guidance", "sds"):
            raise ConfigError(f"`loss` is {self.loss!r}; expected 'guidance' or 'sds'.")
        if self.t_schedule not in ("exponential", "authors"):
            raise ConfigError(
                f"`t_schedule` is {self.t_schedule!r}; expected 'exponential' or 'authors'."
            )
        if not 0 < self.t_end <= self.t_start < 1:
            raise ConfigError(
                f"`t_start`={self.t_start}, `t_end`={self.t_end}: need 0 < t_end <= t_start < 1."
            )
        lo, hi = self.sds_t_range
        if not 0 < lo <= hi < 1:
            raise ConfigError(f"`sds_t_range` {self.sds_t_range} must satisfy 0 < lo <= hi < 1.")
        for name in ("l1_weight", "perceptual_weight", "image_tv_weight"):
            _non_negative(name, getattr(self, name))
        if self.sds_guidance_scale is not None:
            _non_negative("sds_guidance_scale", self.sds_guidance_scale)
        for name in ("lr_grid", "lr_network", "lr_gamma", "sds_weight"):
            _positive(name, getattr(self, name))
        if self.encode_mode not in ("mode", "sample"):
            raise ConfigError(
                f"`encode_mode` is {self.encode_mode!r}; expected 'mode' or 'sample'."
            )


@dataclass(frozen=True, kw_only=True)
class RelightConfig:
    """The two-stage relighting (paper §3.3) and its ablations.

    Attributes:
        stage1: Stage 1 settings; None skips it ("no Stage 1").
        stage2: Stage 2 settings; None skips it ("no Stage 2").
        diffusion: how the diffusion model is called.
        seed: torch seed for ray and view sampling.
    """

    stage1: Stage1Config | None = field(default_factory=Stage1Config)
    stage2: Stage2Config | None = field(default_factory=Stage2Config)
    diffusion: DiffusionSamplingConfig = field(default_factory=DiffusionSamplingConfig)
    seed: int = 0

    def __post_init__(self) -> None:
        if self.stage1 is None and self.stage2 is None:
            raise ConfigError(
                "`stage1` and `stage2` are both None: nothing would be relit. Keep at least one."
            )

    def with_ablation(self, ablation: _AblationArg) -> "RelightConfig":
        """This config turned into one of the paper's ablations (§4.4).

        Args:
            ablation: "full", "no-stage1", "no-stage2", "sds-stage2" or "sds-only".

        Raises:
            ConfigError: on an unknown name, or when the stage it needs is None here.
        """
        s1 = self.stage1 or Stage1Config()
        s2 = self.stage2 or Stage2Config()
        if ablation not in ABLATIONS:
            raise ConfigError(f"`ablation` is {ablation!r}; expected one of {list(ABLATIONS)}.")
        match ablation:
            case "full":
                return replace(self, stage1=s1, stage2=replace(s2, loss="guidance"))
            case "no-stage1":
                return replace(self, stage1=None, stage2=replace(s2, loss="guidance"))
            case "no-stage2":
                return replace(self, stage1=s1, stage2=None)
            case "sds-stage2":
                return replace(self, stage1=s1, stage2=replace(s2, loss="sds"))
            case "sds-only":
                return replace(self, stage1=None, stage2=replace(s2, loss="sds"))
            case _:
                assert_never(ablation)


def fit_preset(name: PresetName) -> FitConfig:
    """A `FitConfig` by name: "paper" (the authors' settings) or "tiny" (CPU tests, seconds).

    Example:
        >>> fit_preset("paper").final_voxels == 300**3
        True
    """
    match name:
        case "paper":
            return FitConfig()
        case "tiny":
            return FitConfig(
                tensorf=TensoRFConfig(
                    density_ranks=(4, 4, 4),
                    appearance_ranks=(8, 8, 8),
                    appearance_dim=12,
                    mlp_hidden=32,
                ),
                scene=SceneBoxConfig(
                    aabb_min=(-1.0, -1.0, -1.0), aabb_max=(1.0, 1.0, 1.0), near=0.5, far=4.0
                ),
                iterations=300,
                batch_rays=1024,
                # TensoRF's density L1 acts on each factor's mean, so on these small factors 8e-5 /
                # 4e-5 pulls hundreds of times harder per element than on the paper's grid: it held
                # a small object's density at zero (8.84 dB, background only). A tenth of it was
                # chosen on the two validation splits (`python benchmarks/nerf_sweep.py run l1`, rule fixed
                # before the run): object PSNR 21.18 vs 19.02 dB at the sizing rule's grid.
                l1_weight_initial=8e-6,
                l1_weight_rest=4e-6,
                initial_voxels=16**3,
                final_voxels=32**3,
                upsample_at=(100, 150),
                alpha_mask_at=(100, 200),
                lr_grid=0.05,
                lr_network=3e-3,
                sizing=GridSizingConfig(max_resolution=48, min_resolution=8),
            )
        case _:
            raise ConfigError(f"`name` is {name!r}; expected 'paper' or 'tiny'.")


def relight_preset(name: PresetName, ablation: Ablation = "full") -> RelightConfig:
    """A `RelightConfig` by name and ablation.

    Example:
        >>> relight_preset("paper").stage2.t_start
        0.4
        >>> relight_preset("tiny", "no-stage2").stage2 is None
        True
    """
    match name:
        case "paper":
            return RelightConfig().with_ablation(ablation)
        case "tiny":
            return RelightConfig(
                # Stage 1 fits the input views times gaffer-tiny's change of shading (box radius
                # 2 px) rather than its blurred views: chosen on the validation split
                # (`python benchmarks/nerf_sweep.py run stage1`, results/nerf_stage1_val.json; rule fixed
                # before the run: lowest ST-LPIPS within 0.25 dB of the model's own views): ST-LPIPS
                # 0.216 vs 0.245, object PSNR 14.59 vs 14.66 dB.
                stage1=Stage1Config(
                    iterations=100,
                    batch_rays=1024,
                    lr_grid=0.05,
                    lr_network=3e-3,
                    target_detail="transfer",
                    transfer_radius_px=2,
                ),
                # Stage 2's learning rates a quarter of the paper's: chosen on a validation split
                # (`python benchmarks/nerf_sweep.py run stage2`, results/nerf_stage2_val.json: 3 unseen
                # objects x forest/studio, 20 steps; the rule, fixed before the run, took the best
                # object PSNR: 14.68 dB vs the paper's 0.02/1e-3 14.56; Stage 1 alone 14.71). No
                # setting tried beat Stage 1 alone there, in PSNR or in ST-LPIPS.
                stage2=Stage2Config(
                    iterations=6, lr_grid=0.005, lr_network=2.5e-4, lr_gamma=0.1 ** (1.0 / 20.0)
                ),
                # sampling: the model's own, from its own initial noise for every view. One shared
                # noise (the 64 px validation's choice, results/nerf_noise_val.json: +0.88 dB) gave
                # every view gaffer-tiny's one-step sample with the same colour error, which the
                # field cannot average away: at the model's 128 px, on 3 unseen validation objects
                # (bench_nerf_cli_defaults.py --validation, results/nerf_cli_defaults_val.json;
                # rule fixed before the run: the best mean object PSNR with no object below its
                # unrelit field) per-view noise won on every object.
                diffusion=DiffusionSamplingConfig(batch_size=4, shared_noise=False),
            ).with_ablation(ablation)
        case _:
            raise ConfigError(f"`name` is {name!r}; expected 'paper' or 'tiny'.")
