"""Camera-frame lighting of a batch: `encode_batch_lighting` (environment maps, one batched
gaffer-envmap call on the training device, no PNG round trip), `batch_lighting` / `batch_lighting_of`
(a batch that mixes environment maps with the authors' pre-encoded maps)."""

import torch
from jaxtyping import Float
from torch import Tensor

from gaffer_diffusion.training.batch import TrainBatch
from gaffer_diffusion.training.config import LightingCompat
from gaffer_diffusion.training.errors import DataError


def encode_batch_lighting(
    envmaps: Float[Tensor, "N He We 3"],
    w2c_blender: Float[Tensor, "N 3 4"],
    *,
    size: int,
    compat: LightingCompat,
    device: torch.device | str | None = None,
) -> tuple[Float[Tensor, "N 3 S S"], Float[Tensor, "N 3 S S"]]:
    """Camera-frame LDR and HDR maps of N (map, pose) pairs in one batched gaffer-envmap call.

    Neural Gaffer §3.2: each map is rotated into its view's camera frame and split into E_L / E_H.

    Returns:
        `(ldr, hdr)`, each `[N, 3, size, size]` float32 in [0, 1] on `device`.
    """
    from gaffer_diffusion.conditioning import LIGHTING_FILTER, LIGHTING_SUPERSAMPLE
    from gaffer_envmap.encode import encode_lighting

    enc = encode_lighting(
        envmaps.to(device=device, dtype=torch.float32),
        w2c_blender.detach().double().cpu(),
        size=size,
        compat=compat,
        filter=LIGHTING_FILTER,  # what the model is sampled with (conditioning.LIGHTING_FILTER)
        supersample=LIGHTING_SUPERSAMPLE,
        device=device,
    )
    return enc.ldr.to(device=device, dtype=torch.float32), enc.hdr.to(
        device=device, dtype=torch.float32
    )


def batch_lighting(
    envmaps: Float[Tensor, "Ne He We 3"],
    w2c_blender: Float[Tensor, "N 3 4"],
    *,
    encoded: Tensor | None = None,
    encoded_ldr: Float[Tensor, "Na 3 S S"] | None = None,
    encoded_hdr: Float[Tensor, "Na 3 S S"] | None = None,
    size: int,
    compat: LightingCompat,
    device: torch.device | str | None = None,
) -> tuple[Float[Tensor, "N 3 S S"], Float[Tensor, "N 3 S S"]]:
    """Camera-frame LDR and HDR maps of N lightings given as environment maps and/or encoded maps.

    Rows where `encoded` is False come from `envmaps` (in order; rotated into the row's camera frame
    and encoded by `encode_batch_lighting`, one call), rows where it is True from `encoded_ldr` /
    `encoded_hdr` (in order; the authors' maps, used as they are).

    Args:
        envmaps: `[Ne, He, We, 3]` the environment maps of the rows with `encoded` False.
        w2c_blender: `[N, 3, 4]` every row's view (only the environment-map rows use it).
        encoded: `[N]` bool, or None when every row is an environment map.
        encoded_ldr: `[Na, 3, size, size]` the pre-encoded LDR maps of the other rows.
        encoded_hdr: `[Na, 3, size, size]` their HDR maps.
        size: output side length.
        compat: gaffer-envmap encoding of the environment maps.
        device: where the result lives.

    Returns:
        `(ldr, hdr)`, each `[N, 3, size, size]` float32 in [0, 1] on `device`.

    Raises:
        DataError: the row counts or map sizes disagree.
    """
    n = int(w2c_blender.shape[0])
    if encoded is None or not bool(encoded.any()):
        if envmaps.shape[0] != n:
            raise DataError(f"{envmaps.shape[0]} environment maps for {n} views.")
        return encode_batch_lighting(envmaps, w2c_blender, size=size, compat=compat, device=device)
    enc = encoded.to(device="cpu", dtype=torch.bool)
    n_enc = int(enc.sum())
    if (
        enc.shape != (n,)
        or encoded_ldr is None
        or encoded_hdr is None
        or encoded_ldr.shape[0] != n_enc
        or encoded_hdr.shape[0] != n_enc
        or envmaps.shape[0] != n - n_enc
    ):
        raise DataError(
            f"`batch_lighting`: {n} views, `encoded` marks {n_enc}, but got {envmaps.shape[0]} "
            "environment maps and "
            f"{None if encoded_ldr is None else encoded_ldr.shape[0]} encoded maps."
        )
    if tuple(encoded_ldr.shape[1:]) != (3, size, size) or encoded_hdr.shape != encoded_ldr.shape:
        raise DataError(
            f"the encoded lighting maps are {tuple(encoded_ldr.shape[1:])}; expected (3, {size}, "
            f"{size}): read the dataset at the model resolution."
        )
    ldr = torch.empty(n, 3, size, size, device=device, dtype=torch.float32)
    hdr = torch.empty_like(ldr)
    ldr[enc.to(ldr.device)] = encoded_ldr.to(device=ldr.device, dtype=torch.float32)
    hdr[enc.to(hdr.device)] = encoded_hdr.to(device=hdr.device, dtype=torch.float32)
    if n_enc < n:
        env_ldr, env_hdr = encode_batch_lighting(
            envmaps, w2c_blender[~enc], size=size, compat=compat, device=device
        )
        ldr[~enc.to(ldr.device)] = env_ldr
        hdr[~enc.to(hdr.device)] = env_hdr
    return ldr, hdr


def batch_lighting_of(
    batch: TrainBatch,
    *,
    size: int,
    compat: LightingCompat,
    device: torch.device | str | None = None,
) -> tuple[Float[Tensor, "BT 3 S S"], Float[Tensor, "BT 3 S S"]]:
    """The `[B*T, 3, size, size]` LDR and HDR maps of every target of `batch` (item-major order)."""
    t = batch.targets_per_sample
    enc = batch.lighting_encoded
    return batch_lighting(
        batch.envmaps.flatten(0, 1),
        batch.w2c_blender.repeat_interleave(t, dim=0),
        encoded=None if enc is None else enc.repeat_interleave(t),
        encoded_ldr=None if batch.encoded_ldr is None else batch.encoded_ldr.flatten(0, 1),
        encoded_hdr=None if batch.encoded_hdr is None else batch.encoded_hdr.flatten(0, 1),
        size=size,
        compat=compat,
        device=device,
    )
