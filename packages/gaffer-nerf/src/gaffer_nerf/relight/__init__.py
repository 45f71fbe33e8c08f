"""Relighting a radiance field with the diffusion prior: Stage 1, Stage 2, and the whole run."""

from gaffer_nerf.relight._common import StageReport
from gaffer_nerf.relight.guard import RelightDivergedError, check_renders_follow_targets
from gaffer_nerf.relight.run import (
    NothingToRelightWarning,
    RelightReport,
    RelightResult,
    relight_field,
)
from gaffer_nerf.relight.stage1 import run_stage1
from gaffer_nerf.relight.stage2 import (
    image_tv,
    run_stage2,
    stage2_for_model,
    target_lost_object,
)

__all__ = [
    "NothingToRelightWarning",
    "RelightDivergedError",
    "RelightReport",
    "RelightResult",
    "StageReport",
    "check_renders_follow_targets",
    "image_tv",
    "relight_field",
    "run_stage1",
    "run_stage2",
    "stage2_for_model",
    "target_lost_object",
]
