"""The re-shading pieces: the learned normal estimator, estimated-geometry hints with the de-lit ratio,
the log-linear residual target, the 0.4 -> 0.5 upgrade and the `normals` / `train-normals` commands."""

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("gaffer_envmap.encode")

from gaffer_diffusion import ConfigError, LightingMaps, RelightingConditions, encode_conditions
from gaffer_diffusion.configs import get_preset
from gaffer_diffusion.geometry.estimator import (
    NormalEstimator,
    NormalEstimatorConfig,
    estimate_normals,
    load_normal_estimator,
)
from gaffer_diffusion.hints import (
    ESTIMATED_HINT_CHANNELS,
    delit_ratio,
    hints_at,
    silhouette_normals,
)
from gaffer_diffusion.models import build_model
from gaffer_diffusion.pipelines import RelightPipeline, SamplingConfig
from gaffer_diffusion.pipelines.relight import _mirror_normals
from gaffer_diffusion.upgrade import to_estimated_geometry, with_new_unet

H = 32


def _disc(h: int = H, r: float = 11.0) -> torch.Tensor:
    yy, xx = torch.meshgrid(torch.arange(h) + 0.5, torch.arange(h) + 0.5, indexing="ij")
    return (((yy - h / 2) ** 2 + (xx - h / 2) ** 2) < r * r).float()[None, None]


def _sphere_normals(mask: torch.Tensor) -> torch.Tensor:
    """Exact camera-frame normals of a sphere filling the disc (x right, y up, z to the camera)."""
    h = mask.shape[-1]
    r = 11.0
    yy, xx = torch.meshgrid(torch.arange(h) + 0.5, torch.arange(h) + 0.5, indexing="ij")
    x, y = (xx - h / 2) / r, -(yy - h / 2) / r
    z = (1 - x * x - y * y).clamp_min(0).sqrt()
    n = torch.stack([x, y, z])[None]
    n = n / n.norm(dim=1, keepdim=True)
    return torch.where(mask > 0.5, n, torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1))


def _linear_to_srgb(x: torch.Tensor) -> torch.Tensor:
    x = x.clamp(0, 1)
    return torch.where(x <= 0.0031308, 12.92 * x, 1.055 * x.pow(1 / 2.4) - 0.055)


def _tiny_estimator(seed: int = 0) -> NormalEstimator:
    torch.manual_seed(seed)
    return NormalEstimator(NormalEstimatorConfig(resolution=32, block_out_channels=(8, 16)))


# --- the estimator ----------------------------------------------------------------------------------


def test_an_untrained_estimator_is_the_silhouette_dome() -> None:
    """Its last convolution starts at zero: before training it returns the dome, not noise."""
    mask = _disc()
    image = torch.rand(1, 3, H, H)
    est = _tiny_estimator().eval()
    with torch.no_grad():
        torch.testing.assert_close(est(image, mask), silhouette_normals(mask), atol=1e-5, rtol=0)


def test_estimated_normals_are_unit_flat_outside_and_mirror_equivariant() -> None:
    est = _tiny_estimator()
    torch.nn.init.normal_(est.unet.conv_out.weight, std=0.05)  # a "trained" one: not the dome
    mask = _disc()
    image = torch.rand(2, 3, H, H)
    masks = mask.expand(2, -1, -1, -1)
    n = estimate_normals(est.eval(), image, masks)
    outside = masks[:, 0] <= 0.5
    torch.testing.assert_close(n.norm(dim=1), torch.ones(2, H, H), atol=1e-4, rtol=0)
    assert bool((n.permute(0, 2, 3, 1)[outside] == torch.tensor([0.0, 0.0, 1.0])).all())
    assert float((n - silhouette_normals(masks)).abs().max()) > 1e-3
    mirrored = estimate_normals(est, image.flip(-1), masks.flip(-1))
    torch.testing.assert_close(mirrored, _mirror_normals(n), atol=1e-5, rtol=0)


def test_estimator_resizes_to_its_resolution_and_back() -> None:
    est = _tiny_estimator().eval()
    mask = _disc(48, 16.0)
    n = estimate_normals(est, torch.rand(1, 3, 48, 48), mask)
    assert n.shape == (1, 3, 48, 48) and bool(torch.isfinite(n).all())


def test_estimator_save_load_round_trip(tmp_path: Path) -> None:
    est = _tiny_estimator()
    torch.nn.init.normal_(est.unet.conv_out.weight, std=0.05)
    est.save(tmp_path / "est", extra={"validation": {"mean_angular_error_deg": 1.0}})
    doc = json.loads((tmp_path / "est" / "gaffer_normals.json").read_text())
    assert doc["config"]["block_out_channels"] == [8, 16] and doc["validation"]
    back = load_normal_estimator(tmp_path / "est")
    x, m = torch.rand(1, 3, H, H), _disc()
    torch.testing.assert_close(estimate_normals(back, x, m), estimate_normals(est.eval(), x, m))


def test_missing_estimator_files_are_named(tmp_path: Path) -> None:
    from gaffer_diffusion.errors import CheckpointNotFoundError

    with pytest.raises(CheckpointNotFoundError, match=r"gaffer_normals\.json"):
        load_normal_estimator(tmp_path)


def test_estimator_config_refuses_a_resolution_its_levels_cannot_halve() -> None:
    with pytest.raises(ConfigError, match="resolution"):
        NormalEstimatorConfig(resolution=30, block_out_channels=(8, 16, 32))


# --- the de-lit ratio ---------------------------------------------------------------------------------


def _lambert(
    normals: torch.Tensor, light_dir: tuple[float, float, float], ambient: float
) -> torch.Tensor:
    d = torch.tensor(light_dir)
    d = (d / d.norm()).view(1, 3, 1, 1)
    return ambient + (normals * d).sum(dim=1, keepdim=True).clamp_min(0.0)


def test_delit_ratio_of_a_sphere_points_where_the_target_light_gains() -> None:
    """A diffuse sphere lit from camera-left, relit from camera-right: the ratio is high on the right,
    low on the left, and (same light both sides) constant = -log(albedo) over the object."""
    mask = _disc()
    n = _sphere_normals(mask)
    albedo = 0.5
    irr_in = _lambert(n, (-1.0, 0.3, 0.6), 0.1).expand(1, 3, H, H)
    image = _linear_to_srgb(albedo * irr_in * 0.5) * mask + (1 - mask)
    irr_tgt = _lambert(n, (1.0, 0.3, 0.6), 0.1).expand(1, 3, H, H) * 0.5
    r = delit_ratio(image, mask, n, irr_tgt)
    inside = mask[0, 0] > 0.5
    right = inside & (torch.arange(H) > H / 2 + 4)[None, :]
    left = inside & (torch.arange(H) < H / 2 - 4)[None, :]
    assert float(r[0, 1][right].mean()) > float(r[0, 1][left].mean()) + 0.2
    assert float(r[:, :, ~inside].abs().max()) == 0.0
    same = delit_ratio(image, mask, n, irr_in * 0.5)
    core = inside & (n[0, 2] > 0.3)  # away from the rim, where antialiasing is absent here anyway
    expected = -math.log(albedo) / 4.0
    assert float((same[0, 1][core] - expected).abs().mean()) < 0.05


def test_estimated_geometry_hints_have_fifteen_channels_and_need_their_inputs() -> None:
    mask = _disc()
    ldr = torch.rand(1, 3, 16, 16)
    hdr = torch.rand(1, 3, 16, 16)
    image = torch.rand(1, 3, H, H)
    n = _sphere_normals(mask)
    h = hints_at(mask, ldr, hdr, H, geometry="estimated", image=image, normals=n)
    assert h.shape == (1, ESTIMATED_HINT_CHANNELS, H, H)
    assert float(h.abs().max()) <= 1.0 + 1e-6
    torch.testing.assert_close(h[:, 9:12], n * mask)  # the normals given are the normals used
    with pytest.raises(ValueError, match="normals"):
        hints_at(mask, ldr, hdr, H, geometry="estimated", image=image)


# --- the log-linear residual and the model config ---------------------------------------------------


def _estimated_preset():
    cfg = get_preset("gaffer-tiny").with_resolution(32)
    return dataclasses.replace(
        cfg,
        unet=dataclasses.replace(cfg.unet, in_channels=16 + ESTIMATED_HINT_CHANNELS),
        vae=dataclasses.replace(cfg.vae, scaling_factor=2.0),
        hint_geometry="estimated",
        residual_space="log_linear",
    )


def test_log_linear_target_round_trips_and_leaves_an_unchanged_pixel_at_zero() -> None:
    model = build_model(_estimated_preset())
    x = torch.rand(2, 4, 8, 8) * 2 - 1
    y = torch.rand(2, 4, 8, 8) * 2 - 1
    z = model.diffusion_target(y, x)
    torch.testing.assert_close(model.decodable_latents(z, x), y, atol=2e-5, rtol=0)
    assert float(model.diffusion_target(x, x).abs().max()) == 0.0
    # a zero prediction returns the input: the input's edges and texture are kept by construction
    torch.testing.assert_close(
        model.decodable_latents(torch.zeros_like(x), x), x, atol=2e-5, rtol=0
    )
    # doubling linear radiance is one constant step, whatever the pixel's texture
    lin = torch.rand(1, 4, 8, 8) * 0.4 + 0.05
    srgb = _linear_to_srgb(lin) * 2 - 1
    brighter = _linear_to_srgb(2 * lin + 0.02) * 2 - 1  # (lin + eps) x 2 - eps with eps = 0.02
    step = model.diffusion_target(brighter, srgb) / 2.0
    torch.testing.assert_close(step, torch.full_like(step, math.log(2.0)), atol=1e-4, rtol=0)


def test_log_linear_needs_a_pixel_space_model() -> None:
    cfg = get_preset("tiny")
    with pytest.raises(ConfigError, match="pixel-space"):
        dataclasses.replace(cfg, residual=True, residual_space="log_linear")


def test_upgrade_keeps_what_the_model_computed_when_the_new_channels_are_zero() -> None:
    old = build_model(get_preset("gaffer-tiny").with_resolution(32), seed=0)
    w = old.unet.conv_in.weight.detach().clone()
    new = to_estimated_geometry(old, scaling_factor=2.0)
    assert new.config.hint_geometry == "estimated" and new.config.residual_space == "log_linear"
    assert (
        new.config.unet.in_channels == 16 + ESTIMATED_HINT_CHANNELS == new.unet.conv_in.in_channels
    )
    torch.testing.assert_close(new.unet.conv_in.weight[:, : w.shape[1]], w)
    assert float(new.unet.conv_in.weight.detach()[:, w.shape[1] :].abs().max()) == 0.0
    with pytest.raises(ConfigError, match="already"):
        to_estimated_geometry(new, scaling_factor=2.0)


def test_a_new_unet_is_wider_seeded_and_keeps_everything_else(tmp_path: Path) -> None:
    from gaffer_diffusion.loading import load_pretrained, save_pretrained
    from gaffer_diffusion.upgrade import main as upgrade_main

    old = build_model(_estimated_preset(), seed=0)
    widths = tuple(2 * c for c in old.config.unet.block_out_channels)
    new = with_new_unet(old, widths, seed=3)
    assert new.unet.config.block_out_channels == widths == new.config.unet.block_out_channels
    assert new.config.unet.in_channels == old.config.unet.in_channels
    assert new.image_encoder is old.image_encoder and new.vae is old.vae
    assert dataclasses.replace(new.config, unet=old.config.unet) == old.config
    again = with_new_unet(old, widths, seed=3).unet.state_dict()
    other = with_new_unet(old, widths, seed=4).unet.state_dict()
    key = "conv_in.weight"
    assert torch.equal(new.unet.state_dict()[key], again[key])
    assert not torch.equal(again[key], other[key])
    with pytest.raises(ConfigError, match="levels"):
        with_new_unet(old, widths[:-1])
    with pytest.raises(ConfigError, match="norm_num_groups"):
        with_new_unet(old, (widths[0] + 1, *widths[1:]))
    # the command writes a folder that loads with the new widths and the old encoder
    save_pretrained(old, tmp_path / "src")
    arg = ",".join(str(c) for c in widths)
    assert (
        upgrade_main([str(tmp_path / "src"), str(tmp_path / "dst"), "--new-unet-channels", arg])
        == 0
    )
    loaded = load_pretrained(tmp_path / "dst").model
    assert loaded.config.unet.block_out_channels == widths
    with pytest.raises(SystemExit):  # a seed with the other upgrade would do nothing: refused
        upgrade_main(
            [str(tmp_path / "src"), str(tmp_path / "x"), "--scaling-factor", "2", "--seed", "1"]
        )
    assert not (tmp_path / "x").exists()
    assert loaded.config.hint_geometry == old.config.hint_geometry


def test_an_estimated_geometry_model_relights_saves_and_loads(tmp_path: Path, monkeypatch) -> None:
    from gaffer_diffusion.geometry import estimator as est_mod
    from gaffer_diffusion.loading import load_pretrained, save_pretrained

    est = _tiny_estimator()
    monkeypatch.setattr(est_mod, "shipped_normal_estimator", lambda: est.eval())
    model = build_model(_estimated_preset(), seed=0)
    mask = _disc()
    image = torch.rand(1, 3, H, H) * mask + (1 - mask)
    maps = LightingMaps(ldr=torch.rand(1, 3, H, H), hdr=torch.rand(1, 3, H, H))
    cond = RelightingConditions(image=image, lighting=maps, mask=mask)
    enc = encode_conditions(model, cond)
    assert enc.hints is not None and enc.hints.shape[1] == ESTIMATED_HINT_CHANNELS
    # the caller's normals (the benchmark's oracle) replace the estimator's
    oracle = RelightingConditions(
        image=image, lighting=maps, mask=mask, normals=_sphere_normals(mask)
    )
    enc_o = encode_conditions(model, oracle)
    assert enc_o.hints is not None
    torch.testing.assert_close(enc_o.hints[:, 9:12], _sphere_normals(mask) * mask)
    sampling = SamplingConfig(num_inference_steps=1, guidance_scale=1.0, mirror_average=True)
    out = RelightPipeline(model)(oracle, sampling, generator=torch.Generator().manual_seed(0))
    assert out.images.shape == (1, 3, H, H) and bool(torch.isfinite(out.images).all())
    save_pretrained(model, tmp_path / "m")
    back = load_pretrained(tmp_path / "m").model
    assert back.config == model.config


def test_oracle_normals_must_match_the_image() -> None:
    from gaffer_diffusion.errors import ShapeError

    maps = LightingMaps(ldr=torch.rand(1, 3, H, H), hdr=torch.rand(1, 3, H, H))
    with pytest.raises(ShapeError, match="normals"):
        RelightingConditions(
            image=torch.rand(1, 3, H, H), lighting=maps, normals=torch.rand(1, 3, 8, 8)
        )


# --- the commands ----------------------------------------------------------------------------------


def _rgba_png(path: Path, size: int = 40) -> Path:
    from PIL import Image

    yy, xx = np.mgrid[:size, :size]
    alpha = (((yy - 20) ** 2 + (xx - 18) ** 2) < 12**2).astype(np.uint8) * 255
    rgba = np.zeros((size, size, 4), np.uint8)
    rgba[..., 0] = (xx * 6).astype(np.uint8)
    rgba[..., 1] = 120
    rgba[..., 3] = alpha
    Image.fromarray(rgba).save(path)
    return path


def test_normals_command_writes_the_photo_sized_normal_map(tmp_path: Path) -> None:
    from PIL import Image

    from gaffer_diffusion.cli import main

    est = _tiny_estimator()
    est.save(tmp_path / "est")
    photo = _rgba_png(tmp_path / "obj.png")
    assert (
        main(
            [
                "normals",
                str(photo),
                "--out",
                str(tmp_path / "n.png"),
                "--estimator",
                str(tmp_path / "est"),
            ]
        )
        == 0
    )
    arr = np.asarray(Image.open(tmp_path / "n.png"))
    assert arr.shape == (40, 40, 3)
    assert bool((arr[0, 0] == 255).all())  # white outside the object
    centre = arr[20, 18].astype(float) / 255 * 2 - 1  # the dome's top faces the camera
    assert centre[2] > 0.9
    assert (
        main(
            [
                "normals",
                str(photo),
                "--out",
                str(tmp_path / "m.png"),
                "--output-size",
                "model",
                "--estimator",
                str(tmp_path / "est"),
            ]
        )
        == 0
    )
    assert np.asarray(Image.open(tmp_path / "m.png")).shape == (32, 32, 3)


def test_normals_command_refuses_bad_arguments_in_one_line(tmp_path: Path, capsys) -> None:
    from gaffer_diffusion.cli import main

    photo = _rgba_png(tmp_path / "obj.png")
    assert main(["normals", str(photo), "--out", str(tmp_path / "n.jpg")]) == 2
    assert "--out" in capsys.readouterr().err
    assert (
        main(
            [
                "normals",
                str(photo),
                "--out",
                str(tmp_path / "n.png"),
                "--estimator",
                str(tmp_path / "nope"),
            ]
        )
        == 2
    )
    assert "--estimator" in capsys.readouterr().err
    assert not (tmp_path / "n.png").exists()


def _geometry_views(n: int, lit: int, size: int = 32, seed: int = 0):
    from gaffer_diffusion.training.normals import GeometryViews

    g = torch.Generator().manual_seed(seed)
    normals = torch.randn(n, 3, size, size, generator=g)
    return GeometryViews(
        images=torch.randint(0, 256, (n, lit, 3, size, size), generator=g, dtype=torch.uint8),
        masks=torch.ones(n, 1, size, size),
        normals_cam=normals / normals.norm(dim=1, keepdim=True),
        object_ids=tuple(f"o{seed}_{i}" for i in range(n)),
    )


def test_concat_views_pools_folders_and_keeps_the_fewest_renders_per_view() -> None:
    from gaffer_diffusion.training.normals import concat_views

    a, b = _geometry_views(3, lit=9, seed=1), _geometry_views(2, lit=5, seed=2)
    both = concat_views([a, b])
    assert both.images.shape == (5, 5, 3, 32, 32) and both.object_ids == a.object_ids + b.object_ids
    assert torch.equal(both.images[:3], a.images[:, :5]) and torch.equal(both.images[3:], b.images)
    assert torch.equal(both.normals_cam[3:], b.normals_cam)
    assert concat_views([a]) is a
    with pytest.raises(ConfigError, match="at least one"):
        concat_views([])
    with pytest.raises(ConfigError, match="differ in size"):
        concat_views([a, _geometry_views(1, lit=5, size=16)])


def test_train_normal_estimator_continues_from_an_estimator() -> None:
    from gaffer_diffusion.geometry.estimator import NormalEstimator, NormalEstimatorConfig
    from gaffer_diffusion.training.normals import NormalTrainConfig, train_normal_estimator

    shapes = NormalEstimatorConfig(resolution=32, block_out_channels=(8, 8, 8, 8))
    torch.manual_seed(0)
    init = NormalEstimator(shapes).eval()
    torch.nn.init.normal_(init.unet.conv_out.weight, std=0.05)  # not the dome any more
    views = _geometry_views(4, lit=2)
    img, mask = views.images[:, 0].float() / 255.0, views.masks
    config = NormalTrainConfig(
        estimator=shapes, max_steps=1, batch_size=2, lr=1e-9, seed=0, threads=1
    )
    with torch.no_grad():
        before = init(img, mask)
    cont, stats = train_normal_estimator(views, config, init=init)
    scratch, _ = train_normal_estimator(views, config)
    with torch.no_grad():
        # one step at a negligible learning rate: the continued estimator is still `init`, the
        # fresh one is still the dome
        assert torch.allclose(cont(img, mask), before, atol=1e-4)
        assert not torch.allclose(scratch(img, mask), before, atol=1e-2)
        assert torch.equal(init(img, mask), before)  # `init` itself is not trained
    assert stats["steps"] == 1.0
    other = NormalTrainConfig(estimator=NormalEstimatorConfig(resolution=32), max_steps=1)
    with pytest.raises(ConfigError, match="same shapes"):
        train_normal_estimator(views, other, init=init)


def test_train_normal_estimator_gives_back_the_callers_thread_count() -> None:
    from gaffer_diffusion.geometry.estimator import NormalEstimatorConfig
    from gaffer_diffusion.training.normals import NormalTrainConfig, train_normal_estimator

    views = _geometry_views(2, lit=2)
    before = torch.get_num_threads()
    other = 1 if before != 1 else 2
    config = NormalTrainConfig(
        estimator=NormalEstimatorConfig(resolution=32, block_out_channels=(8, 8, 8, 8)),
        max_steps=1,
        batch_size=2,
        threads=other,
    )
    train_normal_estimator(views, config)
    assert torch.get_num_threads() == before
