"""Pixel-space models (`VAEConfig.kind="pixel"`), the `gaffer-tiny` preset and `gaffer_diffusion.pretrained`."""

import dataclasses
import json
from pathlib import Path

import pytest
import torch

from gaffer_diffusion import (
    ConfigError,
    RelightPipeline,
    SamplingConfig,
    VAEConfig,
    get_preset,
)
from gaffer_diffusion.configs import ModelConfig
from gaffer_diffusion.errors import CheckpointNotFoundError
from gaffer_diffusion.loading import load_pretrained, model_config_matches, save_pretrained
from gaffer_diffusion.models import PixelAutoencoder, build_model, build_vae
from gaffer_diffusion.testing import random_conditions

pytestmark = pytest.mark.usefixtures("one_thread")


def _small_pixel_config() -> ModelConfig:
    """The `tiny` UNet and CLIP tower on a pixel-space "VAE" at 32 px (fast)."""
    tiny = get_preset("tiny")
    return dataclasses.replace(
        tiny,
        name="tiny-pixel",
        resolution=32,
        unet=dataclasses.replace(tiny.unet, sample_size=32),
        vae=VAEConfig(kind="pixel", scaling_factor=1.0, sample_size=32),
    )


def test_encode_decode_round_trip_is_exact() -> None:
    ae = build_vae(VAEConfig(kind="pixel", scaling_factor=1.0, sample_size=16))
    assert isinstance(ae, PixelAutoencoder)
    assert list(p.numel() for p in ae.parameters()) == [0]
    x = torch.rand(3, 3, 16, 16, generator=torch.Generator().manual_seed(0)) * 2 - 1
    post = ae.encode(x).latent_dist
    z = post.mode()
    assert z.shape == (3, 4, 16, 16)
    assert torch.equal(post.sample(generator=torch.Generator()), z)
    assert torch.equal(z[:, :3], x)
    luma = 0.2126 * x[:, 0] + 0.7152 * x[:, 1] + 0.0722 * x[:, 2]
    torch.testing.assert_close(z[:, 3], luma)
    assert torch.equal(ae.decode(z).sample, x)
    assert torch.equal(post.kl(), torch.zeros(3))


def test_pixel_config_downsampling_and_validation() -> None:
    cfg = _small_pixel_config()
    assert cfg.vae.downsampling_factor == 1 and cfg.latent_size == 32
    with pytest.raises(ConfigError, match=r"vae\.kind"):
        VAEConfig(kind="vq")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"vae\.scaling_factor"):
        VAEConfig(kind="pixel", scaling_factor=0.0)
    with pytest.raises(ConfigError, match=r"vae\.kind"):
        VAEConfig(kind="pixel").to_diffusers()
    with pytest.raises(ConfigError, match=r"unet\.sample_size"):
        dataclasses.replace(cfg, unet=dataclasses.replace(cfg.unet, sample_size=4))


def test_pipeline_runs_in_pixel_space_and_moves_dtype() -> None:
    model = build_model(_small_pixel_config(), seed=0)
    pipe = RelightPipeline(model)
    out = pipe(random_conditions(2, 32), SamplingConfig(num_inference_steps=2), seeds=[0, 1])
    assert out.images.shape == (2, 3, 32, 32) and out.latents.shape == (2, 4, 32, 32)
    assert torch.isfinite(out.images).all()
    assert float(out.images.min()) >= 0 and float(out.images.max()) <= 1
    model.to(dtype=torch.bfloat16)
    assert next(model.vae.parameters()).dtype == torch.bfloat16


def test_save_and_load_pixel_model(tmp_path: Path) -> None:
    model = build_model(_small_pixel_config(), seed=0)
    save_pretrained(model, tmp_path / "m")
    vae_cfg = json.loads((tmp_path / "m" / "vae" / "config.json").read_text())
    assert vae_cfg["_class_name"] == "PixelAutoencoder" and vae_cfg["kind"] == "pixel"
    loaded = load_pretrained(tmp_path / "m").model
    assert isinstance(loaded.vae, PixelAutoencoder)
    assert model_config_matches(loaded.config, model.config)
    for a, b in zip(model.unet.parameters(), loaded.unet.parameters(), strict=True):
        assert torch.equal(a, b)


def test_gaffer_tiny_preset_shapes() -> None:
    cfg = get_preset("gaffer-tiny")
    assert cfg.vae.kind == "pixel" and cfg.resolution == 128 and cfg.latent_size == 128
    assert cfg.hints and cfg.unet.in_channels == 16 + 12 and cfg.unet.sample_size == 128
    # attention only at 16x16: the last down block and the first up block (and the mid block)
    assert cfg.unet.down_block_types == (
        "DownBlock2D",
        "DownBlock2D",
        "DownBlock2D",
        "CrossAttnDownBlock2D",
    )
    assert cfg.unet.up_block_types == ("CrossAttnUpBlock2D", "UpBlock2D", "UpBlock2D", "UpBlock2D")
    model = build_model(cfg, seed=0)
    n = sum(p.numel() for p in model.unet.parameters())
    assert 1_000_000 < n < 6_000_000  # float32 safetensors well under 25 MB


def test_training_loop_trains_a_pixel_model(tmp_path: Path) -> None:
    pytest.importorskip("gaffer_data")
    pytest.importorskip("accelerate")
    from gaffer_diffusion.training import TrainConfig, load_checkpoint_model, train
    from gaffer_diffusion.training.testing import write_synthetic_dataset

    root = write_synthetic_dataset(tmp_path / "data", objects=2, views=2, lightings=3)
    cfg = TrainConfig.from_dict(
        {
            "output_dir": str(tmp_path / "run"),
            "model": {"init": "preset", "preset": "gaffer-tiny", "resolution": 32},
            "data": {"root": str(root), "val_objects": 1, "envmap_height": 8},
            "optim": {"lr": 1e-3, "warmup_steps": 1},
            "train": {
                "max_steps": 2,
                "batch_size": 2,
                "mixed_precision": "no",
                "gradient_checkpointing": False,
                "ema_decay": 0.9,
                "residual_loss_floor": 0.1,  # gaffer-tiny is residual: the weighted loss runs
            },
            "checkpoint": {"every_steps": 2, "keep": 1},
            "logging": {"every_steps": 1, "progress_bar": False, "tensorboard": False},
            "validation": {"every_steps": 0},
        }
    )
    result = train(cfg)
    assert result.step == 2 and all(torch.isfinite(torch.tensor(result.losses)))
    model = load_checkpoint_model(result.checkpoint)
    assert isinstance(model.vae, PixelAutoencoder) and model.config.resolution == 32
    assert result.final_model is not None
    assert isinstance(load_pretrained(result.final_model).model.vae, PixelAutoencoder)


def test_load_gaffer_tiny_names_the_missing_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from gaffer_diffusion import pretrained

    monkeypatch.setattr(pretrained, "gaffer_tiny_path", lambda: tmp_path / "gone")
    with pytest.raises(CheckpointNotFoundError, match=r"gaffer_model\.json"):
        pretrained.load_gaffer_tiny()


def test_shipped_gaffer_tiny_loads_and_relights_the_example() -> None:
    from gaffer_diffusion import pretrained

    if not (pretrained.gaffer_tiny_path() / "gaffer_model.json").is_file():
        pytest.skip("gaffer-tiny weights are not in this checkout")
    model = pretrained.load_gaffer_tiny().model
    assert model.config.name == "gaffer-tiny" and model.config.vae.kind == "pixel"
    example = pretrained.example_dataset_path()
    assert (example / "dataset.json").is_file()
    weights = pretrained.gaffer_tiny_path() / "unet" / "diffusion_pytorch_model.safetensors"
    assert weights.stat().st_size < 25 * 2**20
    res = model.config.resolution
    assert res == 128 and model.config.hints
    out = RelightPipeline(model)(random_conditions(1, res), SamplingConfig(num_inference_steps=2))
    assert out.images.shape == (1, 3, res, res)


def test_prediction_type_is_validated_and_sets_the_training_target() -> None:
    from gaffer_diffusion import SchedulerConfig
    from gaffer_diffusion.training.loop import _prediction_target

    with pytest.raises(ConfigError, match=r"scheduler\.prediction_type"):
        SchedulerConfig(prediction_type="x0")
    assert get_preset("gaffer-tiny").scheduler.prediction_type == "v_prediction"
    z0, noise = torch.full((1, 4, 2, 2), 0.5), torch.full((1, 4, 2, 2), 2.0)
    abar = torch.full((1, 1, 1, 1), 0.36)
    assert torch.equal(_prediction_target("epsilon", z0, noise, abar), noise)
    assert torch.equal(_prediction_target("sample", z0, noise, abar), z0)
    v = _prediction_target("v_prediction", z0, noise, abar)
    torch.testing.assert_close(v, torch.full_like(z0, 0.6 * 2.0 - 0.8 * 0.5))
    with pytest.raises(ConfigError, match=r"scheduler\.prediction_type"):
        _prediction_target("x0", z0, noise, abar)


def test_v_prediction_pipeline_runs() -> None:
    from gaffer_diffusion import SchedulerConfig

    cfg = dataclasses.replace(
        _small_pixel_config(), scheduler=SchedulerConfig(prediction_type="v_prediction")
    )
    pipe = RelightPipeline(build_model(cfg, seed=0))
    for scheduler in ("ddim", "dpmsolver++", "unipc"):
        out = pipe(
            random_conditions(1, 32),
            SamplingConfig(num_inference_steps=2, scheduler=scheduler, guidance_scale=2.0),
            seeds=[0],
        )
        assert torch.isfinite(out.images).all()


def test_gaffer_tiny_samples_from_t999_at_any_step_count() -> None:
    from gaffer_diffusion import SchedulerConfig
    from gaffer_diffusion.schedulers import make_scheduler

    cfg = get_preset("gaffer-tiny").scheduler
    assert cfg.timestep_spacing == "trailing"
    for name in ("ddim", "dpmsolver++", "unipc"):
        for n in (1, 5, 20):
            s = make_scheduler(name, cfg)
            s.set_timesteps(n)
            assert int(s.timesteps[0]) == 999, (name, n)
    # the paper's "leading" schedule would start a 1-step sample at t=1
    s = make_scheduler("ddim", SchedulerConfig())
    s.set_timesteps(1)
    assert int(s.timesteps[0]) == 1
    with pytest.raises(ConfigError, match=r"scheduler\.timestep_spacing"):
        SchedulerConfig(timestep_spacing="uniform")


def test_residual_target_round_trip_and_paper_default_unchanged() -> None:
    g = torch.Generator().manual_seed(0)
    target, image = torch.randn(2, 4, 8, 8, generator=g), torch.randn(2, 4, 8, 8, generator=g)
    paper = build_model(get_preset("tiny"), seed=0)
    assert not paper.config.residual
    # the paper's model: exactly the scaled target latent, as before the option existed
    assert torch.equal(paper.diffusion_target(target, image), target * 0.18215)
    assert torch.equal(paper.decodable_latents(target * 0.18215, image), target * 0.18215 / 0.18215)
    cfg = dataclasses.replace(_small_pixel_config(), residual=True)
    model = build_model(cfg, seed=0)
    z0 = model.diffusion_target(target, image)
    assert torch.equal(z0, target - image)
    torch.testing.assert_close(model.decodable_latents(z0, image), target)
    assert get_preset("gaffer-tiny").residual


def test_residual_pipeline_adds_the_input_back_and_survives_save_load(tmp_path: Path) -> None:
    cfg = dataclasses.replace(_small_pixel_config(), residual=True)
    model = build_model(cfg, seed=0)
    cond = random_conditions(2, 32, seed=3)
    pipe = RelightPipeline(model)
    out = pipe(cond, SamplingConfig(num_inference_steps=2), seeds=[0, 1])
    # pixel space: the image is the sample plus the input, in [-1, 1]
    expected = ((out.latents[:, :3] + cond.image * 2 - 1) / 2 + 0.5).clamp(0, 1)
    torch.testing.assert_close(out.images, expected)
    save_pretrained(model, tmp_path / "m")
    loaded = load_pretrained(tmp_path / "m").model
    assert loaded.config.residual and model_config_matches(loaded.config, cfg)
    again = RelightPipeline(loaded)(cond, SamplingConfig(num_inference_steps=2), seeds=[0, 1])
    torch.testing.assert_close(again.images, out.images)
    manifest = json.loads((tmp_path / "m" / "gaffer_model.json").read_text())
    manifest["config"]["residual"] = "yes"
    (tmp_path / "m" / "gaffer_model.json").write_text(json.dumps(manifest))
    from gaffer_diffusion.errors import CheckpointMismatchError

    with pytest.raises(CheckpointMismatchError, match=r"config\.residual"):
        load_pretrained(tmp_path / "m")


def test_zero_terminal_snr_removes_the_starting_noise_from_a_one_step_sample(
    tmp_path: Path,
) -> None:
    from gaffer_diffusion import SchedulerConfig
    from gaffer_diffusion.schedulers import make_scheduler

    with pytest.raises(ConfigError, match=r"rescale_betas_zero_snr.*epsilon"):
        SchedulerConfig(prediction_type="epsilon", rescale_betas_zero_snr=True)
    zsnr = SchedulerConfig(
        prediction_type="v_prediction", timestep_spacing="trailing", rescale_betas_zero_snr=True
    )
    old = dataclasses.replace(zsnr, rescale_betas_zero_snr=False)
    v = torch.full((1, 4, 2, 2), -0.1)  # a model's v at t=999: "the clean sample is 0.1"
    g = torch.Generator().manual_seed(0)
    z_a, z_b = torch.randn(1, 4, 2, 2, generator=g), torch.randn(1, 4, 2, 2, generator=g)

    def one_step(cfg: SchedulerConfig, z_T: torch.Tensor) -> torch.Tensor:
        s = make_scheduler("ddim", cfg)
        s.set_timesteps(1)
        return s.step(v, s.timesteps[0], z_T).pred_original_sample

    # the paper's schedule keeps sqrt(abar_999) = 0.068 of the starting noise in x0
    leak = one_step(old, z_a) - one_step(old, z_b)
    torch.testing.assert_close(leak, 0.0683 * (z_a - z_b), atol=2e-3, rtol=0.02)
    # at zero terminal SNR, x0 = -v whatever the noise
    torch.testing.assert_close(one_step(zsnr, z_a), torch.full_like(v, 0.1))
    torch.testing.assert_close(one_step(zsnr, z_b), torch.full_like(v, 0.1))
    for name in ("ddim", "dpmsolver++", "unipc"):
        s = make_scheduler(name, zsnr)
        assert float(s.alphas_cumprod[-1]) < 1e-6, name
    cfg = dataclasses.replace(_small_pixel_config(), residual=True, scheduler=zsnr)
    model = build_model(cfg, seed=0)
    save_pretrained(model, tmp_path / "m")
    loaded = load_pretrained(tmp_path / "m").model
    assert loaded.config.scheduler.rescale_betas_zero_snr
    assert model_config_matches(loaded.config, cfg)
    out = RelightPipeline(loaded)(random_conditions(1, 32), SamplingConfig(num_inference_steps=3))
    assert torch.isfinite(out.images).all()


def test_residual_loss_floor_weighs_pairs_by_how_much_their_lighting_changes(
    tmp_path: Path,
) -> None:
    from gaffer_diffusion.training.config import TrainLoopConfig
    from gaffer_diffusion.training.loop import diffusion_loss

    g = torch.Generator().manual_seed(0)
    pred, target = torch.randn(2, 4, 4, 4, generator=g), torch.randn(2, 4, 4, 4, generator=g)
    z0 = torch.stack(
        [torch.full((4, 4, 4), 0.1), torch.full((4, 4, 4), 3.0)]
    )  # small, large change
    plain = diffusion_loss(pred, target, z0, None)
    torch.testing.assert_close(plain, torch.nn.functional.mse_loss(pred, target))
    err = (pred - target).pow(2).mean(dim=(1, 2, 3))
    w = 1.0 / (torch.tensor([0.01, 9.0]) + 0.1)
    torch.testing.assert_close(diffusion_loss(pred, target, z0, 0.1), (err * w / w.mean()).mean())
    # the small-change pair carries almost all the weight; equal errors give the plain loss
    assert float(w[0] / w.mean()) > 1.9
    torch.testing.assert_close(diffusion_loss(pred, pred + 1.0, z0, 0.1), torch.tensor(1.0))
    with pytest.raises(ConfigError, match=r"train\.residual_loss_floor"):
        TrainLoopConfig(residual_loss_floor=0.0)
    # a model that diffuses the target itself has no "change" to weigh by
    pytest.importorskip("gaffer_data")
    pytest.importorskip("accelerate")
    from gaffer_diffusion.training import TrainConfig, train
    from gaffer_diffusion.training.testing import write_synthetic_dataset

    root = write_synthetic_dataset(tmp_path / "data", objects=2, views=2, lightings=3)
    base = {
        "output_dir": str(tmp_path / "run"),
        "model": {"init": "preset", "preset": "tiny"},
        "data": {"root": str(root), "val_objects": 1, "envmap_height": 8},
        "train": {
            "max_steps": 1,
            "batch_size": 2,
            "mixed_precision": "no",
            "gradient_checkpointing": False,
            "residual_loss_floor": 0.1,
        },
        "logging": {"progress_bar": False, "tensorboard": False},
        "validation": {"every_steps": 0},
    }
    with pytest.raises(ConfigError, match=r"residual_loss_floor.*ModelConfig\.residual"):
        train(TrainConfig.from_dict(base))
