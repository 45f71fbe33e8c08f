"""Stop a relighting run whose renders have left their targets: white-out, black-out, NaN.

Both stages only change the appearance, so a relit field that renders its training views white (or
black) where the frozen density holds the object has not relit it but erased it. We saw this
from the CLI's paper preset on a small field: masked PSNR 6.4 dB against 15.7 for the unrelit field,
with a report that said nothing had gone wrong. The check compares the renders with what the run
fitted them to (Stage 1's targets, else the input views) over the object's pixels only (the field's
opacity along each ray above one half), and runs before anything is written, so a failed run leaves
its output folder as it was.
"""

import torch
from jaxtyping import Float
from torch import Tensor

from gaffer_nerf.errors import GafferNerfError, ShapeError

FADE_RATIO = 0.25
"""A render's object contrast (white-out) or brightness (black-out) below this fraction of its
targets' is a divergence: a relighting may brighten or darken the object, but not by a factor of 4
over the whole set of training views while its targets did not."""

MIN_SIGNAL = 0.02
"""Targets whose object contrast (brightness) is below this have none to lose: not judged."""

ADVICE = (
    "try `--preset tiny` (small learning rates, few Stage-2 steps), fewer `--stage2-iterations`, "
    "or `--ablation no-stage2`"
)


class RelightDivergedError(GafferNerfError, RuntimeError):
    """The relit field's renders diverged from their targets (white-out, black-out or NaN)."""


def check_renders_follow_targets(
    renders: Float[Tensor, "V 3 H W"],
    targets: Float[Tensor, "V 3 H W"],
    alpha: Float[Tensor, "V H W"],
    *,
    after: str,
) -> None:
    """Raise when the renders lost the object their targets hold.

    Args:
        renders: the relit field's training views, [0, 1] over a white background.
        targets: what they were fitted to (Stage 1's targets, else the input views).
        alpha: the field's opacity along each training ray; object pixels are those above 0.5.
        after: the stage just run, for the message ("stage 1", "stage 2").

    Raises:
        RelightDivergedError: NaN/Inf in the object's renders, or their contrast against white
            (mean of 1 - colour) or their brightness below `FADE_RATIO` of the targets'; one line
            saying what happened and what to try.
        ShapeError: the three tensors disagree in shape.
    """
    if tuple(renders.shape) != tuple(targets.shape) or renders.ndim != 4:
        raise ShapeError("renders", tuple(renders.shape), str(list(targets.shape)))
    v, _, h, w = renders.shape
    if tuple(alpha.shape) != (v, h, w):
        raise ShapeError("alpha", tuple(alpha.shape), f"[{v}, {h}, {w}]")
    obj = (alpha > 0.5)[:, None].expand_as(renders)
    if not bool(obj.any()):  # no object pixel: nothing to judge
        return
    r, t = renders[obj].float(), targets[obj].float()
    where = f"after {after} the relit field renders its training views"
    tail = f"; nothing was written: {ADVICE}."
    if not bool(torch.isfinite(r).all()):
        raise RelightDivergedError(f"relight diverged: {where} with NaN/Inf colours{tail}")
    contrast_r, contrast_t = float((1.0 - r).mean()), float((1.0 - t).mean())
    if contrast_t > MIN_SIGNAL and contrast_r < FADE_RATIO * contrast_t:
        raise RelightDivergedError(
            f"relight diverged (white-out): {where} white where the object is (contrast "
            f"{contrast_r:.3f} vs {contrast_t:.3f} in its targets){tail}"
        )
    bright_r, bright_t = float(r.mean()), float(t.mean())
    if bright_t > MIN_SIGNAL and bright_r < FADE_RATIO * bright_t:
        raise RelightDivergedError(
            f"relight diverged (black-out): {where} black where the object is (brightness "
            f"{bright_r:.3f} vs {bright_t:.3f} in its targets){tail}"
        )
