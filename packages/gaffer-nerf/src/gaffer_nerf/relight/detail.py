"""Stage-1 targets that keep the input views' texture: the model's change of shading, transferred.

A small relighting model (gaffer-tiny: 128 px, one DDIM step) gets the light right but blurs and
speckles the object's texture, and Stage 1 (paper Eq. 2) bakes whatever the relit views hold into
the field: on the real-render benchmark the relit field's ST-LPIPS was worse than the unrelit
field's. The photo path solved the same problem with detail transfer (`gaffer_diffusion.detail_transfer`):
take from the model only the change of shading, `rho = relit / input` in linear light,
and apply it to the input, `(input_lin + eps) rho - eps`. Here both images are at the view's resolution, so the ratio is smoothed
instead of upsampled: its log is averaged over a (2r+1)^2 box after the pixels near the silhouette
(where the input blends object and white backdrop) are refilled from the interior by push-pull.
Where the light changes slowly the input's texture survives; a change of light sharper than the box
is softened. The radius of the tiny preset was chosen on a validation split
(`python benchmarks/nerf_sweep.py run stage1`, `benchmarks/results/nerf_stage1_val.json`).
"""

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion import detail_transfer as dt
from gaffer_nerf.errors import ShapeError


def transfer_shading(
    inputs_srgb: Float[Tensor, "V 3 H W"],
    relit_srgb: Float[Tensor, "V 3 H W"],
    alpha: Float[Tensor, "V H W"],
    radius_px: int,
) -> Float[Tensor, "V 3 H W"]:
    """The input views with the model's change of shading applied (see the module docstring).

    Args:
        inputs_srgb: the training views under the input lighting, over white, sRGB in [0, 1].
        relit_srgb: the model's relit views in the same frames (over white), sRGB in [0, 1].
        alpha: the views' object coverage in [0, 1].
        radius_px: half-width of the box the log ratio is averaged over (0: pixel by pixel).

    Returns:
        `[V, 3, H, W]` sRGB targets: inside the object the input times the smoothed ratio, outside
        it the relit view (white), blended by `alpha`.

    Raises:
        ShapeError: the three tensors disagree in shape.
    """
    if inputs_srgb.ndim != 4 or inputs_srgb.shape[1] != 3:
        raise ShapeError("inputs_srgb", tuple(inputs_srgb.shape), "[V, 3, H, W]")
    if tuple(relit_srgb.shape) != tuple(inputs_srgb.shape):
        raise ShapeError("relit_srgb", tuple(relit_srgb.shape), str(list(inputs_srgb.shape)))
    v, _, h, w = inputs_srgb.shape
    if tuple(alpha.shape) != (v, h, w):
        raise ShapeError("alpha", tuple(alpha.shape), f"[{v}, {h}, {w}]")
    out = []
    for k in range(v):
        inp = inputs_srgb[k].detach().float().permute(1, 2, 0).cpu().numpy()
        rel = relit_srgb[k].detach().float().permute(1, 2, 0).cpu().numpy()
        a = alpha[k].detach().float().cpu().numpy()
        if not (a > 0.5).any():  # no object in this view: nothing to transfer onto
            out.append(relit_srgb[k].detach().float().cpu())
            continue
        log_rho = dt.log_shading_ratio(inp, rel, a)
        if radius_px > 0:
            log_rho = dt.box_mean(log_rho, radius_px)
        # the inverse of the ratio's definition, so a ratio left as it is gives the relit view back
        # (`apply_shading` scales `photo_lin` alone, which is its own choice for upsampled ratios)
        lim = float(np.log(dt.RATIO_MAX))
        rho = np.exp(np.clip(log_rho, -lim, lim))
        lin = (dt.srgb_to_linear(inp) + dt.EPS_LINEAR) * rho - dt.EPS_LINEAR
        obj = dt.linear_to_srgb(np.clip(lin, 0.0, None))
        blend = a[..., None] * obj + (1.0 - a[..., None]) * rel
        out.append(torch.from_numpy(np.ascontiguousarray(blend)).permute(2, 0, 1))
    return torch.stack(out).to(inputs_srgb.device)
