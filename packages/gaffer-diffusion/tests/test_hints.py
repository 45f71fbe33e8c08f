"""Radiance hints (`gaffer_diffusion.hints`, `ModelConfig.hints`) and hinted models end to end."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F

pytest.importorskip("gaffer_envmap.encode")

from gaffer_diffusion import ConfigError, LightingMaps, RelightingConditions, encode_conditions
from gaffer_diffusion.conditioning import (
    LIGHTING_FILTER,
    EncodedConditions,
    hints_for,
    object_mask_of,
)
from gaffer_diffusion.configs import get_preset
from gaffer_diffusion.hints import (
    HINT_CHANNELS,
    PREFILTER_GRID,
    delit_ratio,
    diffuse_radiance,
    input_radiance_fit,
    prefiltered_maps,
    radiance_from_maps,
    relighting_hints,
    silhouette_normals,
)
from gaffer_diffusion.models import build_model
from gaffer_diffusion.pipelines import RelightPipeline, SamplingConfig
from gaffer_envmap import encode_lighting, orbit_w2c_blender, rotate_to_camera
from gaffer_envmap.augment import mirror_camera_x
from gaffer_envmap.encode import hdr_encode, ldr_encode

H = 64  # mask / image side
S = 32  # lighting map side


def _hdr_env(seed: int = 0) -> np.ndarray:
    """A 16 x 32 world map: random sky, some pixels above 1 and one bright sun pixel."""
    rng = np.random.default_rng(seed)
    env = (rng.random((16, 32, 3)) * 0.8).astype(np.float32)
    env[rng.random((16, 32)) < 0.1] *= 4.0
    env[4, 10] = 60.0
    return env


def _disc(h: int = H, cy: float = H / 2, cx: float = H / 2, r: float = 20.0) -> torch.Tensor:
    yy, xx = torch.meshgrid(torch.arange(h) + 0.5, torch.arange(h) + 0.5, indexing="ij")
    return (((yy - cy) ** 2 + (xx - cx) ** 2) < r * r).float()[None, None]


def _maps(radiance: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """gaffer-envmap's default encoding of a camera-frame radiance map, normalised to its peak."""
    peak = radiance.amax(dim=(1, 2, 3), keepdim=True)
    return ldr_encode(radiance), hdr_encode(radiance, peak)


def _light_at(row: slice, col: slice, ambient: float = 0.05, sun: float = 50.0) -> torch.Tensor:
    rad = torch.full((1, 3, S, S), ambient)
    rad[..., row, col] = sun
    return rad


# --- radiance_from_maps ---------------------------------------------------------------------------


@pytest.mark.parametrize(("az", "el"), [(0.0, 0.0), (37.0, 20.0), (200.0, -30.0)])
def test_radiance_from_maps_recovers_the_encoded_camera_frame_radiance(
    az: float, el: float
) -> None:
    env = _hdr_env()
    pose = orbit_w2c_blender(az, el, 2.0)
    enc = encode_lighting(env, pose, size=S, filter=LIGHTING_FILTER)
    rad = radiance_from_maps(enc.ldr, enc.hdr)
    assert rad.shape == (1, 3, S, S) and rad.dtype == torch.float32
    assert bool(torch.isfinite(rad).all()) and float(rad.min()) >= 0.0
    # the same rotation done directly
    direct = rotate_to_camera(
        env, pose, height=S, width=S, pairing="zip", filter=LIGHTING_FILTER
    ).permute(0, 3, 1, 2)
    assert float(direct.max()) > 10.0 and bool((direct > 1).any())  # real HDR content
    torch.testing.assert_close(rad, direct, rtol=1e-4, atol=1e-5)
    # and it re-encodes to the same maps: E_L = clip(E)^(1/2.2), E_H proportional to log1p(10 E)
    torch.testing.assert_close(rad.clamp(0, 1) ** (1 / 2.2), enc.ldr, atol=1e-5, rtol=0)
    lit = enc.hdr > 1e-3
    ratio = torch.log1p(10 * rad)[lit] / enc.hdr[lit]
    assert float((ratio.max() - ratio.min()) / ratio.mean()) < 1e-4  # one normaliser per map


def test_radiance_from_maps_batches_maps_with_their_own_normalisers() -> None:
    envs = np.stack([_hdr_env(0), _hdr_env(1) * 0.2])
    envs[1, 7, 3] = 500.0  # a much brighter sun: a different HDR normaliser
    pose = orbit_w2c_blender(10.0, 5.0, 2.0)
    enc = encode_lighting(envs, pose, size=16, filter=LIGHTING_FILTER)
    rad = radiance_from_maps(enc.ldr, enc.hdr)
    for i in range(2):
        one = encode_lighting(envs[i], pose, size=16, filter=LIGHTING_FILTER)
        torch.testing.assert_close(rad[i : i + 1], radiance_from_maps(one.ldr, one.hdr))
        direct = rotate_to_camera(
            envs[i], pose, height=16, width=16, pairing="zip", filter=LIGHTING_FILTER
        )
        torch.testing.assert_close(rad[i], direct[0].permute(2, 0, 1), rtol=1e-4, atol=1e-5)


def test_radiance_from_maps_degenerate_maps_stay_finite() -> None:
    zeros = torch.zeros(2, 3, 8, 8)
    rad = radiance_from_maps(zeros, zeros)
    assert bool(torch.isfinite(rad).all()) and float(rad.abs().max()) == 0.0
    # every pixel above 1 (E_L saturated): no pixel fixes the scale; the darkest is taken as 1
    bright = torch.full((1, 3, 8, 8), 5.0)
    bright[..., 0, 0] = 40.0
    ldr, hdr = _maps(bright)
    rad = radiance_from_maps(ldr, hdr)
    assert bool(torch.isfinite(rad).all())
    assert float(rad.min()) == pytest.approx(1.0, rel=1e-4)
    assert float(rad[0, 0, 0, 0]) > float(rad[0, 0, 1, 1])  # the order survives


# --- silhouette_normals ---------------------------------------------------------------------------


def test_silhouette_normals_of_a_disc_form_an_outward_dome() -> None:
    mask = _disc()
    n = silhouette_normals(mask)
    assert n.shape == (1, 3, H, H)
    torch.testing.assert_close(n.norm(dim=1), torch.ones(1, H, H), atol=1e-5, rtol=0)
    inside = mask[0, 0] > 0.5
    assert float(n[0, 2][inside].min()) > 0.0  # facing the camera
    row = col = H // 2
    ys, xs = torch.nonzero(inside, as_tuple=True)
    right = int(xs[ys == row].max())
    left = int(xs[ys == row].min())
    top = int(ys[xs == col].min())  # image rows go down: the top row is camera +y
    bottom = int(ys[xs == col].max())
    assert float(n[0, 0, row, right]) > 0.7  # +x at the right edge
    assert float(n[0, 0, row, left]) < -0.7
    assert float(n[0, 1, top, col]) > 0.7  # +y (up) at the top
    assert float(n[0, 1, bottom, col]) < -0.7
    assert float(n[0, 2, row, col]) > 0.99  # the dome's apex faces the camera
    # outside the mask: the flat (0, 0, 1)
    flat = torch.tensor([0.0, 0.0, 1.0]).view(3, 1)
    assert torch.equal(n[0][:, ~inside], flat.expand(3, int((~inside).sum())))
    # z falls from the centre to the rim along a radius (up to the octagonal metric's ripple)
    z = n[0, 2, row, col : right + 1]
    assert bool((z[1:] <= z[:-1] + 0.01).all()) and float(z[0] - z[-1]) > 0.5


def test_silhouette_normals_of_an_empty_mask_are_flat() -> None:
    n = silhouette_normals(torch.zeros(1, 1, 16, 16))
    assert torch.equal(n, torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1).expand(1, 3, 16, 16))


# --- prefiltered_maps -----------------------------------------------------------------------------


@pytest.mark.parametrize("level", [0.3, 2.0])
def test_prefiltered_maps_of_a_uniform_sky_are_its_radiance(level: float) -> None:
    rad = torch.full((1, 3, S, S), level)
    maps = prefiltered_maps(rad)
    assert maps.shape == (1, 3 * 3, PREFILTER_GRID, PREFILTER_GRID)
    # irradiance / pi of a uniform white sky of radiance L is L; normalised Phong lobes give L
    torch.testing.assert_close(maps[:, :3], torch.full_like(maps[:, :3], level), rtol=0.02, atol=0)
    torch.testing.assert_close(maps[:, 3:], torch.full_like(maps[:, 3:], level), rtol=0.02, atol=0)


def test_diffuse_radiance_is_the_hints_diffuse_channel_before_tone_mapping() -> None:
    mask = _disc()
    normals = silhouette_normals(mask)
    ldr, hdr = _maps(_light_at(slice(4, 8), slice(20, 24)))
    linear = diffuse_radiance(normals, ldr, hdr)
    hint = relighting_hints(mask, ldr, hdr, normals=normals)[:, :3]
    inside = (mask > 0.5).expand_as(linear)
    # the hint is (x / (1 + x))^(1/2.2) mapped to [-1, 1] inside the mask
    toned = (linear / (1 + linear)).pow(1 / 2.2) * 2 - 1
    torch.testing.assert_close(hint[inside], toned[inside], rtol=0, atol=1e-5)
    # a sun off to one side lights the facets that face it: not a constant
    assert float(linear[inside].max()) > 2 * float(linear[inside].min())


def test_input_radiance_fit_recovers_radiance_quadratic_in_the_normal() -> None:
    from gaffer_diffusion.images import linear_to_srgb

    mask = _disc()
    normals = silhouette_normals(mask)
    x, y, z = normals[:, 0:1], normals[:, 1:2], normals[:, 2:3]
    # an order-2 lighting (a light from upper right and its ambient) on a reddish albedo
    shading = 0.25 + 0.15 * x + 0.1 * y + 0.05 * z + 0.05 * x * y
    albedo = torch.tensor([0.9, 0.5, 0.3]).view(1, 3, 1, 1)
    radiance = albedo * shading
    image = torch.where(mask > 0.5, linear_to_srgb(radiance), torch.ones_like(radiance))
    fit = input_radiance_fit(image, mask, normals)
    inside = (mask > 0.5).expand_as(fit)
    # 8-bit-free input, so only the small ridge separates the fit from the truth
    torch.testing.assert_close(fit[inside], radiance[inside], rtol=0.02, atol=2e-3)
    # the de-lit ratio of the input's own lighting is zero: nothing to change
    ratio = delit_ratio(image, mask, normals, shading.expand_as(fit) * albedo)
    assert float(ratio.abs().max()) < 0.01


def test_prefiltered_maps_keep_colour_and_follow_the_light() -> None:
    rad = torch.full((1, 3, S, S), 0.1)
    rad[:, 0] = 0.4  # a red sky
    maps = prefiltered_maps(rad)
    for k in range(3):
        torch.testing.assert_close(
            maps[:, 3 * k], torch.full_like(maps[:, 3 * k], 0.4), rtol=0.02, atol=0
        )
        torch.testing.assert_close(
            maps[:, 3 * k + 1], torch.full_like(maps[:, 3 * k + 1], 0.1), rtol=0.02, atol=0
        )
    # a sun at camera right (centre column, the horizon): the sharp lobe peaks there, and is
    # sharper than the rough lobe, which is sharper than the diffuse one
    sun = prefiltered_maps(_light_at(slice(S // 2 - 1, S // 2 + 1), slice(S // 2 - 1, S // 2 + 1)))
    lum = sun.view(1, 3, 3, PREFILTER_GRID, PREFILTER_GRID).mean(2)[0]  # [lobe, P, P]
    p = PREFILTER_GRID
    peak = divmod(int(lum[2].argmax()), p)
    assert abs(peak[0] - (p - 1) / 2) <= 1 and abs(peak[1] - (p - 1) / 2) <= 1
    contrast = [float(lum[k].max() / lum[k].mean()) for k in range(3)]
    assert contrast[0] < contrast[1] < contrast[2]


# --- relighting_hints -----------------------------------------------------------------------------


def test_hints_shape_range_and_zero_outside_the_mask() -> None:
    mask = torch.cat([_disc(), _disc(cx=24.0, r=12.0)])
    g = torch.Generator().manual_seed(0)
    ldr, hdr = _maps(torch.rand(2, 3, S, S, generator=g) ** 4 * 8)
    h = relighting_hints(mask, ldr, hdr)
    assert h.shape == (2, HINT_CHANNELS, H, H) == (2, 12, H, H)
    assert bool(torch.isfinite(h).all())
    assert float(h.min()) >= -1.0 and float(h.max()) <= 1.0
    outside = (mask <= 0.5).expand_as(h)
    assert float(h[outside].abs().max()) == 0.0
    # inside: the shading hints are not constant, the normals are unit length
    inside = mask[:, 0] > 0.5
    assert float(h[:, 0][inside].std()) > 0.01
    torch.testing.assert_close(
        h[:, 9:].norm(dim=1)[inside], torch.ones(int(inside.sum())), atol=1e-5, rtol=0
    )


def test_light_from_camera_right_brightens_the_right_half() -> None:
    mask = _disc()
    ldr, hdr = _maps(_light_at(slice(S // 2 - 1, S // 2 + 1), slice(S // 2 - 1, S // 2 + 1)))
    h = relighting_hints(mask, ldr, hdr)
    inside = mask[0, 0] > 0.5
    cols = torch.arange(H).view(1, H).expand(H, H) + 0.5
    right, left = inside & (cols > H / 2), inside & (cols < H / 2)
    for k in range(3):  # diffuse, then both glossy lobes
        hint = h[0, 3 * k : 3 * k + 3].mean(0)
        assert float(hint[right].mean()) > float(hint[left].mean()) + 0.05, k
        assert float(hint[right].max()) > float(hint[left].max()) + 0.1, k
    diffuse = h[0, :3].mean(0)
    assert float(diffuse[right].mean()) > float(diffuse[left].mean()) + 0.2
    # the sharp highlight sits on the right half, near the disc's equator
    sharp = h[0, 6:9].mean(0).masked_fill(~inside, -2.0)
    row, col = divmod(int(sharp.argmax()), H)
    assert col > H / 2 and abs(row + 0.5 - H / 2) < 6


def test_light_from_camera_up_brightens_the_top_half() -> None:
    mask = _disc()
    ldr, hdr = _maps(_light_at(slice(0, 2), slice(0, S)))  # the rows around camera +y
    h = relighting_hints(mask, ldr, hdr)
    inside = mask[0, 0] > 0.5
    rows = torch.arange(H).view(H, 1).expand(H, H) + 0.5
    top, bottom = inside & (rows < H / 2), inside & (rows > H / 2)
    diffuse = h[0, :3].mean(0)
    assert float(diffuse[top].mean()) > float(diffuse[bottom].mean()) + 0.1


def test_hints_are_mirror_equivariant() -> None:
    ellipse = _disc()
    yy, xx = torch.meshgrid(torch.arange(H) + 0.5, torch.arange(H) + 0.5, indexing="ij")
    ellipse = ((((yy - 28) / 14) ** 2 + ((xx - 38) / 22) ** 2) < 1).float()[None, None]
    ellipse[..., 10:20, 8:18] = 1.0  # an asymmetric blob
    mask = torch.cat([ellipse, _disc(cx=26.0, r=15.0)])
    g = torch.Generator().manual_seed(1)
    ldr, hdr = _maps(torch.rand(2, 3, S, S, generator=g) ** 4 * 5)
    h = relighting_hints(mask, ldr, hdr)
    m = relighting_hints(mask.flip(-1), mirror_camera_x(ldr), mirror_camera_x(hdr)).flip(-1)
    torch.testing.assert_close(m[:, :9], h[:, :9], atol=1e-4, rtol=0)
    torch.testing.assert_close(m[:, 9], -h[:, 9], atol=1e-4, rtol=0)  # normal x flips sign
    torch.testing.assert_close(m[:, 10:], h[:, 10:], atol=1e-4, rtol=0)
    # and the test has teeth: without mirroring the maps the hints differ
    wrong = relighting_hints(mask.flip(-1), ldr, hdr).flip(-1)
    assert float((wrong[:, :9] - h[:, :9]).abs().max()) > 0.05


# --- hinted models --------------------------------------------------------------------------------


def _hinted_tiny_config():
    tiny = get_preset("tiny")
    return dataclasses.replace(
        tiny, hints=True, unet=dataclasses.replace(tiny.unet, in_channels=16 + 12)
    )


@pytest.fixture(scope="module")
def hinted_model():
    return build_model(_hinted_tiny_config(), seed=0)


def _conditions_on_white(b: int = 2, res: int = 64, seed: int = 0) -> RelightingConditions:
    g = torch.Generator().manual_seed(seed)
    mask = torch.cat([_disc(res, r=res / 3), _disc(res, cx=res / 3, r=res / 5)])[:b]
    colour = torch.rand(b, 3, res, res, generator=g) * 0.8
    image = mask * colour + (1 - mask)
    ldr, hdr = _maps(torch.rand(b, 3, res, res, generator=g) ** 4 * 5)
    return RelightingConditions(image=image, lighting=LightingMaps(ldr=ldr, hdr=hdr), mask=mask)


def test_presets_hints() -> None:
    tiny = get_preset("gaffer-tiny")
    assert tiny.hints and tiny.hint_channels == 12 and tiny.unet.in_channels == 28
    paper = get_preset("neural-gaffer-256")
    assert not paper.hints and paper.hint_channels == 0 and paper.unet.in_channels == 16
    assert not get_preset("tiny").hints and get_preset("tiny").unet.in_channels == 16


def test_hint_channels_must_match_in_channels() -> None:
    tiny = get_preset("tiny")
    with pytest.raises(ConfigError, match="in_channels"):
        dataclasses.replace(tiny, unet=dataclasses.replace(tiny.unet, in_channels=28))
    with pytest.raises(ConfigError, match="hint"):
        dataclasses.replace(tiny, hints=True)  # 16 channels but hints asked for
    assert _hinted_tiny_config().hint_channels == 12


def test_encode_conditions_adds_the_hints(hinted_model) -> None:
    cond = _conditions_on_white()
    enc = encode_conditions(hinted_model, cond)
    h = hinted_model.config.latent_size
    assert enc.hints is not None and enc.hints.shape == (2, 12, h, h)
    cat = enc.concat_latents()
    assert cat.shape == (2, 24, h, h)
    assert torch.equal(cat[:, 12:], enc.hints)
    ref = F.interpolate(
        relighting_hints(cond.mask, cond.lighting.ldr, cond.lighting.hdr), size=(h, h), mode="area"
    )
    torch.testing.assert_close(enc.hints, ref)
    # without a mask the non-white pixels of an image on white stand in for it
    no_mask = RelightingConditions(image=cond.image, lighting=cond.lighting)
    torch.testing.assert_close(object_mask_of(cond.image), cond.mask)
    torch.testing.assert_close(hints_for(no_mask, h), enc.hints)
    # the batch helpers carry the hints along
    assert torch.equal(enc.select([1]).hints, enc.hints[1:])
    assert enc.repeat_interleave(2).hints.shape == (4, 12, h, h)
    both = EncodedConditions.cat([enc, enc.select([0])])
    assert both.hints is not None and torch.equal(both.hints[2], enc.hints[0])
    # an unhinted model's conditions have none
    plain = encode_conditions(build_model(get_preset("tiny"), seed=0), cond)
    assert plain.hints is None and plain.concat_latents().shape[1] == 12


def test_relight_pipeline_runs_a_hinted_model(hinted_model) -> None:
    cond = _conditions_on_white()
    pipe = RelightPipeline(hinted_model)
    out = pipe(cond, SamplingConfig(num_inference_steps=1), seeds=[0, 1])
    assert out.images.shape == (2, 3, 64, 64) and bool(torch.isfinite(out.images).all())
    # the hints reach the UNet: other lighting, other hints, another image (same noise)
    other = dataclasses.replace(
        cond,
        lighting=LightingMaps(ldr=cond.lighting.ldr.flip(-2), hdr=cond.lighting.hdr.flip(-2)),
    )
    out2 = pipe(other, SamplingConfig(num_inference_steps=1), seeds=[0, 1])
    assert not torch.allclose(out.images, out2.images)
    # mirror averaging (hints of the mirrored input) and no guidance also run
    mirrored = pipe(
        cond,
        SamplingConfig(num_inference_steps=1, guidance_scale=1.0, mirror_average=True),
        seeds=[0, 1],
    )
    assert mirrored.images.shape == (2, 3, 64, 64)


def test_save_load_round_trip_keeps_hints(hinted_model, tmp_path: Path) -> None:
    from gaffer_diffusion.errors import CheckpointMismatchError
    from gaffer_diffusion.loading import (
        MANIFEST_NAME,
        load_pretrained,
        model_config_matches,
        save_pretrained,
    )

    folder = save_pretrained(hinted_model, tmp_path / "hinted")
    manifest = json.loads((folder / MANIFEST_NAME).read_text())
    assert manifest["config"]["hints"] is True
    loaded = load_pretrained(folder).model
    assert loaded.config.hints and loaded.config.unet.in_channels == 28
    assert model_config_matches(loaded.config, hinted_model.config)
    cond = _conditions_on_white()
    sampling = SamplingConfig(num_inference_steps=1)
    a = RelightPipeline(hinted_model)(cond, sampling, seeds=[0, 1]).images
    b = RelightPipeline(loaded)(cond, sampling, seeds=[0, 1]).images
    torch.testing.assert_close(a, b)
    # a manifest that lost the flag cannot describe a 28-channel UNet
    del manifest["config"]["hints"]
    (folder / MANIFEST_NAME).write_text(json.dumps(manifest))
    with pytest.raises(ConfigError, match="in_channels"):
        load_pretrained(folder)
    manifest["config"]["hints"] = "yes"
    (folder / MANIFEST_NAME).write_text(json.dumps(manifest))
    with pytest.raises(CheckpointMismatchError, match="hints"):
        load_pretrained(folder)
    # an unhinted model saves hints false and loads back unhinted
    plain = save_pretrained(build_model(get_preset("tiny"), seed=0), tmp_path / "plain")
    assert json.loads((plain / MANIFEST_NAME).read_text())["config"]["hints"] is False
    assert not load_pretrained(plain).model.config.hints
