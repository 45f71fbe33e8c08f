"""Stage 1's sampler option: `--scheduler` / `DiffusionSamplingConfig.scheduler` reach the pipeline's
own DPM-Solver++ / UniPC (no second sampler in gaffer-nerf), and bad combinations are refused early."""

from pathlib import Path
from typing import Any

import jaxtyping
import pytest
import torch

from gaffer_diffusion import SCHEDULERS, DefaultSampling, RelightPipeline, SamplingConfig
from gaffer_diffusion.testing import random_conditions, tiny_model
from gaffer_nerf.cli import main
from gaffer_nerf.configs import SAMPLER_LABELS, SAMPLERS, DiffusionSamplingConfig
from gaffer_nerf.errors import ConfigError
from gaffer_nerf.guidance import DiffusionGuide
from gaffer_nerf.testing import write_sphere_scene


@pytest.fixture(scope="module")
def pipe() -> RelightPipeline:
    return RelightPipeline(tiny_model())


def test_samplers_are_gaffer_diffusions() -> None:
    assert set(SAMPLERS) <= set(SCHEDULERS) and set(SAMPLER_LABELS) == set(SAMPLERS)


def test_refusals_name_the_flag() -> None:
    # the test-time type hook refuses a name outside the Literal first; without it, ConfigError
    with pytest.raises((ConfigError, jaxtyping.TypeCheckError), match=r"scheduler.*'euler'"):
        DiffusionSamplingConfig(scheduler="euler")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"--steps 20"):
        DiffusionSamplingConfig(scheduler="unipc", num_inference_steps=1)
    # the model's own one step (gaffer-tiny) is too few for a multistep solver asked alone
    one_step = DefaultSampling(num_inference_steps=1, guidance_scale=1.0)
    with pytest.raises(ConfigError, match=r"multistep"):
        DiffusionSamplingConfig(scheduler="dpmpp-2m").resolved(one_step)
    assert DiffusionSamplingConfig().resolved(one_step).scheduler == "ddim"  # the paper's


@pytest.mark.parametrize("scheduler", ["dpmpp-2m", "unipc"])
def test_stage1_relights_with_the_pipelines_solver(pipe: RelightPipeline, scheduler: Any) -> None:
    steps = 4
    guide = DiffusionGuide(
        pipe,
        DiffusionSamplingConfig(num_inference_steps=steps, scheduler=scheduler, batch_size=2),
    )
    cfg = guide.sampling_config()
    assert (cfg.scheduler, cfg.num_inference_steps) == (scheduler, steps)
    cond = random_conditions(3, 64, seed=4)
    views = guide.encode_views(cond.image, cond.lighting)
    got = guide.relight_views(views)
    # exactly what the pipeline samples with that solver, view i from seed i
    want = pipe.sample(
        views.encoded,
        SamplingConfig(num_inference_steps=steps, guidance_scale=3.0, scheduler=scheduler),
        seeds=[0, 1, 2],
    ).images
    torch.testing.assert_close(got, want, atol=1e-5, rtol=1e-5)
    ddim = DiffusionGuide(pipe, DiffusionSamplingConfig(num_inference_steps=steps, batch_size=2))
    assert ddim.sampling_config().scheduler == "ddim"
    assert float((ddim.relight_views(views) - got).abs().max()) > 1e-3  # the solver took effect
    # Stage 2's targets run the same solver from t* (its steps below 0.6 T)
    _, ts = pipe.img2img_timesteps(0.6, cfg)
    out = guide.denoise_from(cond.image, views.encoded, 0.6, generator=torch.Generator())
    assert len(ts) >= 2 and bool(torch.isfinite(out).all())


def test_cli_scheduler_flag(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    scene = write_sphere_scene(tmp_path / "scene", train_views=2, test_views=1, resolution=32)
    field = tmp_path / "field"
    fit = ["fit", str(scene.root), "--out", str(field), "--preset", "tiny", "--iterations", "10"]
    assert main([*fit, "--device", "cpu", "--no-progress"]) == 0
    seen: list[SamplingConfig] = []
    sample = RelightPipeline.sample

    def rec(p: Any, encoded: Any, sampling: Any = None, **kw: Any) -> Any:
        seen.append(sampling)
        return sample(p, encoded, sampling, **kw)

    monkeypatch.setattr(RelightPipeline, "sample", rec)
    base = [
        "relight", str(field), "--data", str(scene.root), "--target-lighting", "1",
        "--envmaps", str(scene.envmap_dir), "--preset", "tiny", "--stage1-iterations", "2",
        "--ablation", "no-stage2", "--device", "cpu", "--no-progress",
    ]  # fmt: skip
    capsys.readouterr()
    flags = ["--scheduler", "dpmpp-2m", "--steps", "3", "--out", str(tmp_path / "r")]
    assert main([*base, *flags]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("relight with"))
    assert "3 DPM-Solver++ steps" in line
    assert "precision:" not in out  # gaffer-tiny under `auto` stays float32: nothing to say
    assert [(c.scheduler, c.num_inference_steps) for c in seen] == [("dpmpp-2m", 3)]
    # gaffer-tiny's own single step is too few for it: refused before anything is sampled
    seen.clear()
    bad = ["--scheduler", "unipc", "--out", str(tmp_path / "bad")]
    assert main([*base, *bad]) == 2
    assert "--steps 20" in capsys.readouterr().err and not seen
    assert not (tmp_path / "bad").exists()
