"""Relight's preset follows the fit, Stage 2 never follows a target that erased the
object, and a run whose renders diverge from their targets stops before writing anything."""

import dataclasses
import json
from pathlib import Path

import pytest
import torch

from gaffer_diffusion import RelightPipeline
from gaffer_diffusion.testing import tiny_model
from gaffer_nerf.cli import main
from gaffer_nerf.configs import relight_preset
from gaffer_nerf.guidance import DiffusionGuide, unavailable_perceptual
from gaffer_nerf.relight import (
    RelightDivergedError,
    check_renders_follow_targets,
    relight_field,
    stage2_for_model,
)
from gaffer_nerf.rendering import build_weight_cache, render_cached
from gaffer_nerf.testing import write_sphere_scene


def _object_contrast(field, scene) -> float:
    """Mean darkness (1 - colour) of the training views' object pixels: 0 when they render white."""
    cache = build_weight_cache(field, scene.train.cameras.rays())
    with torch.no_grad():
        rgb = render_cached(field, cache, torch.arange(cache.num_rays))
    obj = (1.0 - cache.background) > 0.5
    return float((1.0 - rgb[obj]).mean())


def test_paper_stage2_does_not_follow_a_target_that_erased_the_object(fitted, scene) -> None:
    # gaffer-tiny's partial denoise of a Stage-1 render (t* = 0.4) returned the object as white on a
    # 128 px Cycles object; the paper's Stage 2 (learning rate 0.02, 500 steps) followed it
    # into a white field. The same target here: all white.
    cfg = relight_preset("paper", "no-stage1")
    cfg = dataclasses.replace(cfg, stage2=dataclasses.replace(cfg.stage2, iterations=20))
    guide = DiffusionGuide(RelightPipeline(tiny_model()), cfg.diffusion)
    guide.denoise_from = lambda images, *a, **k: torch.ones_like(images)  # type: ignore[method-assign]
    before = _object_contrast(fitted.field, scene)
    res = relight_field(
        fitted.field, scene.train, scene.env_target, guide, cfg, unavailable_perceptual("test")
    )
    after = _object_contrast(res.field, scene)
    assert before > 0.2
    assert after > 0.9 * before, (before, after)  # today: the object fades toward white
    assert res.report.stage2 is not None and res.report.stage2.skipped_targets == 20


def test_stage2_still_follows_a_target_that_holds_the_object(fitted, scene) -> None:
    cfg = relight_preset("paper", "no-stage1")
    cfg = dataclasses.replace(cfg, stage2=dataclasses.replace(cfg.stage2, iterations=5))
    guide = DiffusionGuide(RelightPipeline(tiny_model()), cfg.diffusion)
    guide.denoise_from = lambda images, *a, **k: images * 0.8  # type: ignore[method-assign]
    res = relight_field(
        fitted.field, scene.train, scene.env_target, guide, cfg, unavailable_perceptual("test")
    )
    assert res.report.stage2 is not None and res.report.stage2.skipped_targets == 0
    assert _object_contrast(res.field, scene) > _object_contrast(fitted.field, scene)


def _views(value: float) -> torch.Tensor:
    return torch.full((2, 3, 8, 8), value)


def test_guard_names_white_out_black_out_and_nan() -> None:
    alpha = torch.zeros(2, 8, 8)
    alpha[:, 2:6, 2:6] = 1.0
    check_renders_follow_targets(_views(0.5), _views(0.45), alpha, after="stage 1")  # close: fine
    with pytest.raises(RelightDivergedError, match="white") as white:
        check_renders_follow_targets(_views(0.99), _views(0.5), alpha, after="stage 2")
    assert "\n" not in str(white.value) and "--preset tiny" in str(white.value)
    with pytest.raises(RelightDivergedError, match="black"):
        check_renders_follow_targets(_views(0.01), _views(0.5), alpha, after="stage 2")
    nan = _views(0.5)
    nan[0, 0, 3, 3] = float("nan")
    with pytest.raises(RelightDivergedError, match="NaN"):
        check_renders_follow_targets(nan, _views(0.5), alpha, after="stage 1")
    # no object pixel: nothing to judge
    check_renders_follow_targets(_views(0.99), _views(0.5), torch.zeros(2, 8, 8), after="stage 2")


def test_relight_takes_the_fits_preset_and_says_so(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    s = write_sphere_scene(tmp_path / "scene", train_views=6, test_views=2, resolution=32)
    data, field = str(s.root), tmp_path / "field"
    common = ["--device", "cpu", "--no-progress"]
    fit = ["fit", data, "--out", str(field), "--preset", "tiny", "--iterations", "40", *common]
    assert main(fit) == 0
    assert json.loads((field / "fit_report.json").read_text())["preset"] == "tiny"
    relight = [
        "relight", str(field), "--data", data, "--target-lighting", "1", "--envmaps",
        str(s.envmap_dir), "--diffusion-preset", "tiny", "--stage1-iterations", "3",
        "--stage2-iterations", "1", "--steps", "2", *common,
    ]  # fmt: skip
    capsys.readouterr()
    assert main([*relight, "--out", str(tmp_path / "r1")]) == 0
    out = capsys.readouterr().out
    assert "preset tiny (the field's fit" in out
    report = json.loads((tmp_path / "r1" / "relight_report.json").read_text())
    assert report["preset"] == "tiny" and report["config"]["stage1"]["batch_rays"] == 1024
    assert main([*relight, "--out", str(tmp_path / "r2"), "--preset", "paper"]) == 0
    assert "preset paper (--preset)" in capsys.readouterr().out
    # a relit field relit again: the preset its own relight recorded
    again = [*relight, "--out", str(tmp_path / "r3")]
    again[1] = str(tmp_path / "r1")
    assert main(again) == 0
    assert "preset tiny (the field's fit" in capsys.readouterr().out


def test_a_diverging_run_stops_in_one_line_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import gaffer_nerf.relight.run as run_mod

    s = write_sphere_scene(tmp_path / "scene", train_views=6, test_views=2, resolution=32)
    data, field, out = str(s.root), tmp_path / "field", tmp_path / "relit"
    common = ["--device", "cpu", "--no-progress"]
    assert (
        main(["fit", data, "--out", str(field), "--preset", "tiny", "--iterations", "40", *common])
        == 0
    )

    def white_out(field, *args, **kwargs):  # a Stage 2 that drives every colour to white
        with torch.no_grad():
            field.mlp.layers[-1].bias.fill_(30.0)
        return None

    monkeypatch.setattr(run_mod, "run_stage2", white_out)
    capsys.readouterr()
    code = main([
        "relight", str(field), "--data", data, "--target-lighting", "1", "--envmaps",
        str(s.envmap_dir), "--diffusion-preset", "tiny", "--stage1-iterations", "3",
        "--stage2-iterations", "1", "--steps", "2", "--out", str(out), *common,
    ])  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and "white" in err[0] and "nothing was written" in err[0]
    assert not out.exists()


def test_relight_output_is_complete_or_absent(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # relit_views/ used to be written after the field and its report: a failure in between left a
    # relit field without its views (or beside an earlier run's). The set is built beside --out now.
    import gaffer_nerf.evaluate as evaluate_mod

    s = write_sphere_scene(tmp_path / "scene", train_views=6, test_views=2, resolution=32)
    data, field, out = str(s.root), tmp_path / "field", tmp_path / "relit"
    common = ["--device", "cpu", "--no-progress"]
    fit = ["fit", data, "--out", str(field), "--preset", "tiny", "--iterations", "40", *common]
    assert main(fit) == 0
    relight = [
        "relight", str(field), "--data", data, "--target-lighting", "1", "--envmaps",
        str(s.envmap_dir), "--diffusion-preset", "tiny", "--stage1-iterations", "3",
        "--stage2-iterations", "1", "--steps", "2", "--out", str(out), *common,
    ]  # fmt: skip
    real_write = evaluate_mod.write_images

    def disk_full(images, folder, names):  # the relit views fail after the field was saved
        real_write(images[:1], folder, names[:1])
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(evaluate_mod, "write_images", disk_full)
    assert main(relight) == 2
    assert not out.exists()  # today: the field and its report, without relit_views
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []

    monkeypatch.setattr(evaluate_mod, "write_images", real_write)
    assert main(relight) == 0
    before = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert Path("relit_views/005.png") in before and Path("relight_report.json") in before
    (out / "notes.txt").write_text("mine")  # not relight's: kept by a rerun
    monkeypatch.setattr(evaluate_mod, "write_images", disk_full)
    assert main(relight) == 2  # a failed rerun leaves the earlier run as it was
    after = {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after == {**before, Path("notes.txt"): b"mine"}
    monkeypatch.setattr(evaluate_mod, "write_images", real_write)
    assert main(relight) == 0
    assert (out / "notes.txt").read_text() == "mine" and (out / "relit_views" / "000.png").is_file()
    capsys.readouterr()


def test_stage2_is_off_for_a_model_that_samples_in_one_step() -> None:
    paper = relight_preset("paper")
    cfg, why = stage2_for_model(paper, 1)
    assert cfg.stage2 is None and cfg.stage1 == paper.stage1
    assert why is not None and "one step" in why and "--ablation full" in why
    assert stage2_for_model(paper, 50) == (paper, None)  # a model that denoises from any level
    for ablation in ("no-stage1", "sds-stage2"):  # explicit choices are kept
        explicit = relight_preset("paper", ablation)
        assert stage2_for_model(explicit, 1) == (explicit, None)


def test_relight_defaults_keep_stage1_targets_for_a_one_step_model(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # gaffer-tiny samples in one step: its partial denoise from t* = 0.4 whitened a small field's
    # object. Before, the defaults ran Stage 2 with it; now they keep Stage 1's targets.
    import gaffer_nerf.cli as cli_mod
    from gaffer_diffusion import DefaultSampling
    from gaffer_nerf.guidance.model import RelightingModel, smoke_model

    one_step = DefaultSampling(num_inference_steps=1, guidance_scale=1.0, source="test")
    model = RelightingModel(
        pipeline=RelightPipeline(smoke_model(), default_sampling=one_step), name="one-step smoke"
    )
    monkeypatch.setattr(cli_mod, "_load_diffusion", lambda *a, **k: model)
    s = write_sphere_scene(tmp_path / "scene", train_views=6, test_views=2, resolution=32)
    data, field = str(s.root), tmp_path / "field"
    common = ["--device", "cpu", "--no-progress"]
    fit = ["fit", data, "--out", str(field), "--preset", "tiny", "--iterations", "40", *common]
    assert main(fit) == 0
    relight = [
        "relight", str(field), "--data", data, "--target-lighting", "1", "--envmaps",
        str(s.envmap_dir), "--stage1-iterations", "3", *common,
    ]  # fmt: skip
    capsys.readouterr()
    assert main([*relight, "--out", str(tmp_path / "r1")]) == 0
    out = capsys.readouterr().out
    assert "stage 2 off: the model samples in one step" in out and "(no-stage2" in out
    report = json.loads((tmp_path / "r1" / "relight_report.json").read_text())
    assert report["config"]["stage2"] is None and report["report"]["stage2"] is None
    assert "one step" in report["stage2_off"]
    # asked for by name, Stage 2 runs
    assert main([*relight, "--out", str(tmp_path / "r2"), "--ablation", "full"]) == 0
    report = json.loads((tmp_path / "r2" / "relight_report.json").read_text())
    assert report["report"]["stage2"]["iterations"] == 6 and report["stage2_off"] is None
    assert "stage 2 off" not in capsys.readouterr().out
