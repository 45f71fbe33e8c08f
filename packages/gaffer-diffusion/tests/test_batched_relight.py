"""`relight_in_batches`: the one batching loop gives the images of one call."""

import torch

from gaffer_diffusion import build_model, get_preset
from gaffer_diffusion.conditioning import LightingMaps, RelightingConditions
from gaffer_diffusion.pipelines import (
    RelightPipeline,
    SamplingConfig,
    relight_built_batches,
    relight_in_batches,
)


def test_chunks_equal_one_call_with_shared_and_per_item_inputs() -> None:
    pipe = RelightPipeline(build_model(get_preset("tiny"), seed=0))
    g = torch.Generator().manual_seed(0)
    n = 5
    image = torch.rand(1, 3, 64, 64, generator=g)
    mask = (torch.rand(1, 1, 64, 64, generator=g) > 0.5).float()
    maps = LightingMaps(
        ldr=torch.rand(n, 3, 64, 64, generator=g), hdr=torch.rand(n, 3, 64, 64, generator=g)
    )
    sampling = SamplingConfig(num_inference_steps=2)
    whole = pipe(
        RelightingConditions(
            image=image.expand(n, -1, -1, -1), lighting=maps, mask=mask.expand(n, -1, -1, -1)
        ),
        sampling,
        seeds=[7] * n,
    ).images
    batches = list(
        relight_in_batches(pipe, image, maps, sampling, seeds=7, batch_size=2, mask=mask)
    )
    assert [(b.start, b.stop) for b in batches] == [(0, 2), (2, 4), (4, 5)]
    torch.testing.assert_close(torch.cat([b.output.images for b in batches]), whole)

    per_item = image.expand(n, -1, -1, -1).clone()
    per_item[3] = 1.0 - per_item[3]
    seeds = [10 + i for i in range(n)]
    ref = pipe(RelightingConditions(image=per_item, lighting=maps), sampling, seeds=seeds).images
    got = torch.cat(
        [
            b.output.images
            for b in relight_in_batches(pipe, per_item, maps, sampling, seeds=seeds, batch_size=3)
        ]
    )
    torch.testing.assert_close(got, ref)
    assert not torch.allclose(got[3], whole[3])  # per-item inputs and seeds were used


def test_a_per_batch_builder_is_called_per_call_and_equals_one_call() -> None:
    pipe = RelightPipeline(build_model(get_preset("tiny"), seed=0))
    g = torch.Generator().manual_seed(1)
    n = 5
    images = torch.rand(n, 3, 64, 64, generator=g)
    maps = LightingMaps(
        ldr=torch.rand(n, 3, 64, 64, generator=g), hdr=torch.rand(n, 3, 64, 64, generator=g)
    )
    sampling = SamplingConfig(num_inference_steps=2)
    whole = pipe(RelightingConditions(image=images, lighting=maps), sampling, seeds=[3] * n).images
    events: list[tuple[str, int, int]] = []

    def build(lo: int, hi: int) -> RelightingConditions:
        events.append(("build", lo, hi))
        part = LightingMaps(ldr=maps.ldr[lo:hi], hdr=maps.hdr[lo:hi])
        return RelightingConditions(image=images[lo:hi], lighting=part)

    got = []
    for b in relight_built_batches(pipe, n, build, sampling, seeds=3, batch_size=2):
        events.append(("relit", b.start, b.stop))
        got.append(b.output.images)
    # each batch's conditions are built just before its call (lazily), in order
    assert events == [
        ("build", 0, 2),
        ("relit", 0, 2),
        ("build", 2, 4),
        ("relit", 2, 4),
        ("build", 4, 5),
        ("relit", 4, 5),
    ]
    torch.testing.assert_close(torch.cat(got), whole)
    tensors = relight_in_batches(pipe, images, maps, sampling, seeds=3, batch_size=2)
    torch.testing.assert_close(torch.cat([b.output.images for b in tensors]), whole)
