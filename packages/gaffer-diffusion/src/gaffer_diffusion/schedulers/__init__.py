"""Samplers for the relighting model: the authors' DDIM and faster multistep solvers, one noise schedule.

All samplers share the training schedule of `SchedulerConfig` (scaled-linear betas 0.00085-0.012, 1000
steps, epsilon prediction). DDIM with 50 "leading" steps and eta 0 is the paper's setting (and the
default under `--compat neural-gaffer`); DPM-Solver++ (2M, `"dpmpp-2m"`) and UniPC (bh2) are diffusers'
second-order multistep solvers that reach similar quality in 15-25 steps. They convert
epsilon, v and sample predictions to the same data prediction, so every checkpoint's prediction type
runs; a prediction type diffusers' solvers do not take is refused by `make_scheduler`.
"""

from typing import assert_never

from diffusers.schedulers.scheduling_ddim import DDIMScheduler
from diffusers.schedulers.scheduling_dpmsolver_multistep import DPMSolverMultistepScheduler
from diffusers.schedulers.scheduling_unipc_multistep import UniPCMultistepScheduler

from gaffer_diffusion._choices import MULTISTEP_SCHEDULERS as MULTISTEP_SCHEDULERS
from gaffer_diffusion._choices import SCHEDULERS as SCHEDULERS  # the CLI's choices, torch-free
from gaffer_diffusion._choices import SchedulerName as SchedulerName
from gaffer_diffusion.configs import SchedulerConfig
from gaffer_diffusion.errors import ConfigError

SOLVER_PREDICTION_TYPES: tuple[str, ...] = ("epsilon", "v_prediction", "sample")
"""What DPM-Solver++ and UniPC convert to their data prediction (diffusers' `convert_model_output`)."""

Sampler = DDIMScheduler | DPMSolverMultistepScheduler | UniPCMultistepScheduler
"""What `make_scheduler` returns: the diffusers scheduler of one of `SCHEDULERS`."""


def make_scheduler(
    name: SchedulerName,
    config: SchedulerConfig | None = None,
    *,
    timestep_spacing: str | None = None,
) -> Sampler:
    """A fresh diffusers scheduler of the given kind for the model's noise schedule.

    Args:
        name: "ddim" (authors, eta 0), "dpmpp-2m" (DPM-Solver++ 2M; "dpmsolver++" is its earlier
            spelling) or "unipc" (UniPC bh2).
        config: the training schedule; None for the authors' defaults.
        timestep_spacing: override of `config.timestep_spacing` ("leading", "trailing", "linspace").

    Returns:
        A new scheduler (schedulers are stateful: make one per sampling call).

    Raises:
        ConfigError: on an unknown `name`, or a multistep solver with a prediction type it does not
            convert (diffusers' solvers take epsilon, v_prediction and sample).

    Example:
        >>> s = make_scheduler("ddim")
        >>> s.set_timesteps(50)
        >>> s.timesteps[:2].tolist(), int(s.timesteps[-1])
        ([981, 961], 1)
    """
    cfg = config or SchedulerConfig()
    common = {
        "num_train_timesteps": cfg.num_train_timesteps,
        "beta_start": cfg.beta_start,
        "beta_end": cfg.beta_end,
        "beta_schedule": cfg.beta_schedule,
        "prediction_type": cfg.prediction_type,
        "steps_offset": cfg.steps_offset,
        "timestep_spacing": timestep_spacing or cfg.timestep_spacing,
        "rescale_betas_zero_snr": cfg.rescale_betas_zero_snr,
    }
    if name not in SCHEDULERS:
        raise ConfigError(f"`scheduler` is {name!r}; expected one of {list(SCHEDULERS)}.")
    if name in MULTISTEP_SCHEDULERS and cfg.prediction_type not in SOLVER_PREDICTION_TYPES:
        raise ConfigError(
            f"`scheduler` {name!r} cannot sample a model with prediction type "
            f"{cfg.prediction_type!r} (it takes {', '.join(SOLVER_PREDICTION_TYPES)}); use "
            "`--scheduler ddim`."
        )
    match name:
        case "ddim":
            return DDIMScheduler(
                **common, clip_sample=cfg.clip_sample, set_alpha_to_one=cfg.set_alpha_to_one
            )
        case "dpmpp-2m" | "dpmsolver++":
            return DPMSolverMultistepScheduler(
                **common, algorithm_type="dpmsolver++", solver_order=2, lower_order_final=True
            )
        case "unipc":
            return UniPCMultistepScheduler(**common, solver_order=2, predict_x0=True)
        case _:
            assert_never(name)


__all__ = [
    "MULTISTEP_SCHEDULERS",
    "SCHEDULERS",
    "SOLVER_PREDICTION_TYPES",
    "Sampler",
    "SchedulerName",
    "make_scheduler",
]
