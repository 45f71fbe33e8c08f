"""Every path that samples the relighting model uses the model's own suggested sampling.

The sampler is monkeypatched to record what it receives; a path that falls back to other defaults
(the paper's 50 steps / CFG 3, no mirror average, the authors' encoding) fails here.
"""

import json
from pathlib import Path
from typing import Any

import pytest
import torch

from gaffer_diffusion import LoadedModel, RelightPipeline
from gaffer_diffusion.demo import load_model, sampling_for
from gaffer_nerf.cli import main
from gaffer_nerf.configs import DiffusionSamplingConfig, relight_preset
from gaffer_nerf.guidance import DiffusionGuide, load_relighting_model, smoke_model
from gaffer_nerf.guidance.diffusion import DiffusionGuide as _Guide
from gaffer_nerf.testing import write_sphere_scene


@pytest.fixture(scope="module")
def gaffer_diffusion_choice() -> tuple[Any, str]:
    """What gaffer-diffusion itself samples gaffer-tiny with (`gaffer-diffusion relight`/demo)."""
    loaded = load_model(None)
    return sampling_for(loaded, None, None), str(loaded.default_sampling.compat)


class Recorder:
    """Wraps the places the model is sampled: the pipeline (Stage 1), its img2img (Stage 2 targets),
    its noise prediction (SDS), the img2img schedule, and the guide's lighting."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.sample_configs: list[Any] = []
        self.sample_batches: list[int] = []
        self.eps_guidance: list[float] = []
        self.eps_batches: list[int] = []
        self.schedule_steps: list[int] = []
        self.compat: list[str] = []
        sample, denoise = RelightPipeline.sample, RelightPipeline.denoise_from
        predict = RelightPipeline.predict_noise
        timesteps, lighting = RelightPipeline.img2img_timesteps, _Guide.lighting

        def rec_sample(pipe: Any, encoded: Any, sampling: Any = None, **kw: Any) -> Any:
            self.sample_configs.append(sampling)
            self.sample_batches.append(encoded.batch_size)
            return sample(pipe, encoded, sampling, **kw)

        def rec_denoise(
            pipe: Any, images: Any, t: float, enc: Any, sampling: Any = None, **kw: Any
        ) -> Any:
            self.eps_guidance.append(float(sampling.guidance_scale))
            mirrored = kw.get("mirrored") is not None  # the mirrors run in the same batch
            self.eps_batches.append(int(images.shape[0]) * (2 if mirrored else 1))
            return denoise(pipe, images, t, enc, sampling, **kw)

        def rec_predict(pipe: Any, z_t: Any, t: Any, enc: Any, **kw: Any) -> Any:  # SDS
            self.eps_guidance.append(float(kw["guidance_scale"]))
            self.eps_batches.append(int(z_t.shape[0]))
            return predict(pipe, z_t, t, enc, **kw)

        def rec_timesteps(pipe: Any, t_frac: float, sampling: Any = None) -> Any:
            sched, ts = timesteps(pipe, t_frac, sampling)
            self.schedule_steps.append(len(sched.timesteps))  # the whole schedule it set
            return sched, ts

        def rec_lighting(guide: Any, envmap: Any, w2c: Any) -> Any:
            self.compat.append(guide.sampling.compat)
            return lighting(guide, envmap, w2c)

        monkeypatch.setattr(RelightPipeline, "sample", rec_sample)
        monkeypatch.setattr(RelightPipeline, "denoise_from", rec_denoise)
        monkeypatch.setattr(RelightPipeline, "predict_noise", rec_predict)
        monkeypatch.setattr(RelightPipeline, "img2img_timesteps", rec_timesteps)
        monkeypatch.setattr(_Guide, "lighting", rec_lighting)


def _scene(tmp_path: Path) -> Any:
    return write_sphere_scene(tmp_path / "scene", train_views=3, test_views=1, resolution=32)


def _fit(tmp_path: Path, scene: Any) -> Path:
    field = tmp_path / "field"
    fit = ["fit", str(scene.root), "--out", str(field), "--preset", "tiny", "--iterations", "20"]
    assert main([*fit, "--device", "cpu", "--no-progress"]) == 0
    return field


def _relight(scene: Any, field: Path, out: Path, *extra: str) -> list[str]:
    return [
        "relight", str(field), "--data", str(scene.root), "--target-lighting", "1",
        "--envmaps", str(scene.envmap_dir), "--out", str(out), "--preset", "tiny",
        "--stage1-iterations", "2", "--stage2-iterations", "2", "--device", "cpu",
        "--no-progress", *extra,
    ]  # fmt: skip


def test_suggestions_come_from_the_model() -> None:
    tiny = load_relighting_model(None)
    # read once from its folder; a pipeline built in memory around the same model agrees
    assert tiny.suggested == tiny.pipeline.default_sampling
    assert tiny.suggested == RelightPipeline(tiny.model).default_sampling
    # the demo's and the app's loaded-model record, shared: the 3D stages only add their names
    assert isinstance(tiny, LoadedModel) and tiny.suggested is tiny.default_sampling
    assert tiny.describe().startswith(f"{tiny.name} ({tiny.source}); its sampling: ")
    s = tiny.suggested
    assert (s.num_inference_steps, s.guidance_scale, s.mirror_average, s.compat) == (
        1,
        1.0,
        True,
        "default",
    )
    smoke = RelightPipeline(smoke_model()).default_sampling  # none of its own: the paper's
    assert (smoke.num_inference_steps, smoke.guidance_scale, smoke.compat) == (
        50,
        3.0,
        "neural-gaffer",
    )


def test_cli_without_checkpoint_samples_gaffer_tiny_its_own_way(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    gaffer_diffusion_choice: tuple[Any, str],
) -> None:
    expected, compat = gaffer_diffusion_choice
    scene = _scene(tmp_path)
    field = _fit(tmp_path, scene)
    rec = Recorder(monkeypatch)
    capsys.readouterr()
    assert main(_relight(scene, field, tmp_path / "full")) == 0  # Stage 1 + Stage 2 guidance
    line = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("relight with")]
    assert len(line) == 1 and "gaffer-tiny" in line[0] and "no `--checkpoint` given" in line[0]
    assert "1 DDIM step, guidance 1" in line[0] and "mirror average on" in line[0]
    # Stage 1: the pipeline got exactly gaffer-diffusion's setting, on views + their mirrors
    assert rec.sample_configs and all(c == expected for c in rec.sample_configs)
    assert rec.sample_batches == [6]  # 3 views + 3 mirrors in one batch
    # Stage 2 guidance: the model's schedule and CFG, mirrored batch
    assert rec.schedule_steps and set(rec.schedule_steps) == {expected.num_inference_steps}
    assert set(rec.eps_guidance) == {expected.guidance_scale} and set(rec.eps_batches) == {2}
    assert set(rec.compat) == {compat}
    report = json.loads((tmp_path / "full" / "relight_report.json").read_text())
    used = report["config"]["diffusion"]
    assert (used["num_inference_steps"], used["mirror_average"], used["compat"]) == (
        1,
        True,
        "default",
    )

    rec.eps_guidance.clear()
    rec.eps_batches.clear()
    assert main(_relight(scene, field, tmp_path / "sds", "--ablation", "sds-only")) == 0
    assert set(rec.eps_guidance) == {expected.guidance_scale}  # SDS: the model's CFG, not 3
    assert set(rec.eps_batches) == {1} and len(rec.eps_batches) == 4  # view + mirror, 2 steps


def test_flags_override_the_suggestion(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    scene = _scene(tmp_path)
    field = _fit(tmp_path, scene)
    rec = Recorder(monkeypatch)
    flags = ["--steps", "2", "--no-mirror-average", "--guidance", "1.5", "--ablation", "no-stage2"]
    assert main(_relight(scene, field, tmp_path / "r", *flags)) == 0
    assert "flags over the model's suggestion" in capsys.readouterr().out
    (cfg,) = rec.sample_configs
    assert (cfg.num_inference_steps, cfg.guidance_scale, cfg.mirror_average) == (2, 1.5, False)
    assert rec.sample_batches == [3]


def test_guide_resolves_every_unset_field() -> None:
    model = load_relighting_model(None)
    guide = DiffusionGuide(RelightPipeline(model.model), relight_preset("tiny").diffusion)
    s, m = guide.sampling, model.suggested
    assert (s.num_inference_steps, s.guidance_scale, s.average_samples) == (
        m.num_inference_steps,
        m.guidance_scale,
        m.average_samples,
    )
    assert (s.mirror_average, s.compat, s.latent_mode) == (m.mirror_average, m.compat, "mode")
    # a one-step model whose step is above t*: Stage 2 takes one step from t* (not from t = 999)
    _, ts = guide.pipeline.img2img_timesteps(0.4, guide.sampling_config())
    assert ts.tolist() == [400]
    mine = DiffusionGuide(
        RelightPipeline(model.model), DiffusionSamplingConfig(compat="neural-gaffer")
    )
    assert mine.sampling.latent_mode == "sample"  # the authors' encoding brings their latent mode
    assert mine.sampling.num_inference_steps == 1


def test_mirror_average_needs_the_mirrored_conditions() -> None:
    guide = DiffusionGuide(RelightPipeline(load_relighting_model(None).model))
    x = torch.rand(1, 3, 128, 128)
    from gaffer_diffusion import LightingMaps

    views = guide.encode_views(x, LightingMaps(ldr=x, hdr=x))
    assert views.mirrored is not None
    with pytest.raises(ValueError, match="mirror"):
        guide.denoise_from(x, views.encoded, 0.3)
    out = guide.denoise_from(x, views.encoded, 0.3, mirrored=views.mirrored)
    assert out.shape == (1, 3, 128, 128) and bool(torch.isfinite(out).all())


def test_envmap_sanitize_and_bundled_names(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    scene = _scene(tmp_path)
    field = _fit(tmp_path, scene)  # a real field: preflight checks it before the env map
    out = tmp_path / "r"
    capsys.readouterr()
    args = [
        "relight", str(field), "--data", str(scene.root), "--envmap", "sunset",
        "--out", str(out), "--no-progress", "--device", "cpu",
    ]  # fmt: skip
    assert main([*args, "--sanitize", "strict"]) == 2  # refused before loading anything
    err = capsys.readouterr().err
    assert "--sanitize zero" in err and len(err.strip().splitlines()) <= 3
    assert main([*args[:5], "no-such-hdri", *args[6:]]) == 2
    assert "bundled HDRI" in capsys.readouterr().err and not out.exists()
