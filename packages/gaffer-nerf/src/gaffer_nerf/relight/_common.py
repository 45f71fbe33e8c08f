"""Shared pieces of the relighting stages."""

from dataclasses import dataclass

import torch

from gaffer_nerf.fields.tensorf import TensoRFVM


@dataclass(frozen=True, kw_only=True)
class StageReport:
    """What one relighting stage did.

    Attributes:
        name: "stage1" or "stage2".
        iterations: steps taken.
        seconds: wall time of the optimisation (not counting relit views or cache).
        losses: loss after every step.
        t_star: Stage 2 with the guidance loss: t* at every step (empty otherwise).
        loss_kind: "l2" (Stage 1), "guidance" or "sds" (Stage 2).
        sds_non_finite: Stage 2 with the SDS loss: gradient values that were NaN or infinite and were
            zeroed (0 otherwise; see `DiffusionGuide.sds_non_finite`).
        skipped_targets: Stage 2 with the guidance loss: steps whose target had lost the object
            (faded to white or black where the render holds it) and were not taken.
    """

    name: str
    iterations: int
    seconds: float
    losses: tuple[float, ...]
    t_star: tuple[float, ...] = ()
    loss_kind: str = ""
    sds_non_finite: int = 0
    skipped_targets: int = 0


def appearance_optimizer(
    field: TensoRFVM, lr_grid: float, lr_network: float, betas: tuple[float, float]
) -> torch.optim.Adam:
    """Adam over the appearance only: planes/lines at `lr_grid`, basis + MLP at `lr_network`."""
    return torch.optim.Adam(
        [
            {"params": field.appearance_grid_parameters(), "lr": lr_grid},
            {"params": field.network_parameters(), "lr": lr_network},
        ],
        betas=betas,
    )
