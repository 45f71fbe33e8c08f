"""`gaffer-diffusion demo` (README's main job) and `relight` without `--checkpoint` (gaffer-tiny).

A tiny random model relights a tiny synthetic gaffer-data example written without Blender.
"""

import json
import logging
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

pytest.importorskip("gaffer_data")
pytest.importorskip("gaffer_envmap.encode")

from gaffer_diffusion.cli import main
from gaffer_diffusion.demo import DemoConfig, load_model, run_demo
from gaffer_diffusion.errors import CheckpointNotFoundError, ConfigError, DatasetError
from gaffer_diffusion.loading import MANIFEST_NAME, save_pretrained
from gaffer_diffusion.metrics import ImageScores
from gaffer_diffusion.report import LightingRow, ReportContent, image_links, render_html
from gaffer_diffusion.testing import tiny_model, write_tiny_render_dataset

FRAMES = 3


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory) -> Path:
    return save_pretrained(tiny_model(), tmp_path_factory.mktemp("demo") / "model")


@pytest.fixture(scope="module")
def example(tmp_path_factory) -> Path:
    return write_tiny_render_dataset(tmp_path_factory.mktemp("demo") / "example")


@pytest.fixture(scope="module")
def demo_out(tmp_path_factory, model_dir, example) -> Path:
    out = tmp_path_factory.mktemp("demo") / "out"
    args = ["demo", "--out", str(out), "--checkpoint", str(model_dir), "--example", str(example)]
    assert main([*args, "--steps", "2", "--frames", str(FRAMES), "--threads", "1"]) == 0
    return out


def _bundled_count() -> int:
    from gaffer_envmap.bundled import bundled_hdris

    return len(bundled_hdris())


def test_demo_writes_every_artifact(demo_out) -> None:
    for name in ("report.html", "metrics.json", "turntable.gif", "overview.png"):
        assert (demo_out / name).is_file(), name
    # lighting 0 is the input; lightings 1 and 2 have ground truth; every bundled HDRI is an extra
    relit = sorted(p.name for p in (demo_out / "relit").glob("*.png"))
    assert len(relit) == 2 + _bundled_count()
    assert sorted(p.name for p in (demo_out / "ground_truth").glob("*.png")) == [
        "001_cool.png",
        "002_warm.png",
    ]
    assert len(list((demo_out / "turntable").glob("frame_*.png"))) == FRAMES
    with Image.open(demo_out / "turntable.gif") as gif:
        assert gif.n_frames == FRAMES
    with Image.open(demo_out / "relit" / "001_cool.png") as im:
        assert im.size == (64, 64)  # the tiny model's resolution
    assert not list(demo_out.rglob(".*.tmp*")), "atomic writes left temporary files"


def test_report_links_only_to_files_that_exist(demo_out) -> None:
    page = (demo_out / "report.html").read_text(encoding="utf-8")
    links = image_links(page)
    assert len(links) > 20
    for link in links:
        assert not Path(link).is_absolute() and ".." not in link, link
        assert (demo_out / link).is_file(), link
    for text in ("PSNR", "SSIM", "stlpips-alex", "unrelit input", "channel-aligned", "Timings"):
        assert text in page
    assert "turntable.gif" in links and "ground_truth/001_cool.png" in links


def test_metrics_json_has_scores_baselines_and_timings(demo_out) -> None:
    m = json.loads((demo_out / "metrics.json").read_text())
    assert m["schema"] == "gaffer.demo_metrics"
    assert m["settings"]["num_inference_steps"] == 2
    assert m["settings"]["device"] == "cpu" and m["settings"]["torch_threads"] == 1
    # `dtype` "auto" as `relight` defaults to: a small UNet stays float32
    assert m["settings"]["dtype"] == "float32"
    assert m["summary"].startswith("object mask: PSNR")
    assert 0.0 <= m["closer_than_input"] <= 1.0
    for variant in ("object_raw", "object_aligned", "raw", "aligned_image", "aligned_mask"):
        for who in (m["means"]["relit"], m["means"]["baselines"]["input"]):
            assert math.isfinite(who[variant]["psnr"]) and 0 <= who[variant]["ssim"] <= 1
    assert [it["name"] for it in m["items"]] == ["001_cool", "002_warm"]
    for it in m["items"]:
        assert (
            set(it["relit"])
            == set(it["baseline_input"])
            == {
                "object_raw",
                "object_aligned",
                "raw",
                "aligned_image",
                "aligned_mask",
            }
        )
        assert (demo_out / it["files"]["ground_truth"]).is_file()
    assert len(m["extra"]) == _bundled_count()
    t = m["timings"]
    assert len(t["sampling_batches_s"]) == math.ceil((2 + _bundled_count() + FRAMES) / 8)
    assert 0 < t["sampling_per_image_s"] < t["sampling_s"] <= t["total_s"]
    assert m["turntable"]["frames"] == FRAMES and m["turntable"]["gif"] == "turntable.gif"


def test_target_maps_are_the_evaluation_maps_and_the_turntable_spins_the_most_directional_hdri(
    example,
) -> None:
    from gaffer_diffusion.conditioning import lighting_from_envmap
    from gaffer_diffusion.demo import _lightings, _read_example
    from gaffer_diffusion.evaluation import pair_lighting
    from gaffer_envmap import directionality
    from gaffer_envmap.bundled import bundled_hdris, read_bundled_hdri

    ex = _read_example(example, "auto", 64)
    config = DemoConfig(out=Path("unused"), frames=4, extra_hdris=False)
    jobs = _lightings(ex, config, 64, "neural-gaffer")
    targets = [j for j in jobs if j.kind == "target"]
    frames = [j for j in jobs if j.kind == "turntable"]
    assert len(targets) == 2 and len(frames) == 4
    ref = pair_lighting(ex.pairs, 64, "neural-gaffer")
    torch.testing.assert_close(torch.cat([j.maps.ldr for j in targets]), ref.ldr)
    torch.testing.assert_close(torch.cat([j.maps.hdr for j in targets]), ref.hdr)
    # the turntable spins the bundled HDRI whose diffuse light changes most about up, from spin 0
    scores = {n: directionality(read_bundled_hdri(n), about_up=True) for n in bundled_hdris()}
    best = max(scores, key=scores.__getitem__)
    assert frames[0].label.startswith(f"{best}, spun 0 deg")
    w2c = torch.tensor(ex.w2c_blender[None])
    first = lighting_from_envmap(read_bundled_hdri(best), w2c, size=64, compat="neural-gaffer")
    torch.testing.assert_close(frames[0].maps.ldr, first.ldr, atol=1e-5, rtol=0)
    assert not torch.allclose(frames[1].maps.hdr, frames[0].maps.hdr)
    # a named one wins; an unknown name is refused before any sampling
    named = _lightings(
        ex, DemoConfig(out=Path("u"), frames=2, turntable_hdri="studio"), 64, "default"
    )
    assert [j.label.split(",")[0] for j in named if j.kind == "turntable"] == ["studio"] * 2
    with pytest.raises(ConfigError, match="turntable_hdri"):
        _lightings(ex, DemoConfig(out=Path("u"), frames=2, turntable_hdri="nope"), 64, "default")


def test_demo_is_batch_invariant(tmp_path, model_dir, example, demo_out) -> None:
    config = DemoConfig(
        out=tmp_path / "b1",
        checkpoint=model_dir,
        example=example,
        num_inference_steps=2,
        frames=0,
        batch_size=1,
        extra_hdris=False,
    )
    result = run_demo(config)
    assert result.turntable_gif is None and result.images == 2
    for name in ("001_cool", "002_warm"):
        a = np.asarray(Image.open(demo_out / "relit" / f"{name}.png"))
        b = np.asarray(Image.open(tmp_path / "b1" / "relit" / f"{name}.png"))
        assert np.abs(a.astype(int) - b.astype(int)).max() <= 1


def test_out_that_is_a_file_is_refused(tmp_path, model_dir, example, capsys) -> None:
    out = tmp_path / "report.html"
    out.write_text("not a folder")
    args = ["demo", "--out", str(out), "--checkpoint", str(model_dir), "--example", str(example)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "`--out`" in err and str(out) in err and "folder" in err
    with pytest.raises(ConfigError, match="--out"):
        run_demo(DemoConfig(out=out, checkpoint=model_dir, example=example))


def test_missing_checkpoint_names_the_argument(tmp_path, example, capsys) -> None:
    missing = tmp_path / "no-such-model"
    args = ["demo", "--out", str(tmp_path / "o"), "--checkpoint", str(missing)]
    assert main([*args, "--example", str(example)]) == 2
    err = capsys.readouterr().err
    assert "`--checkpoint`" in err and str(missing) in err
    not_ours = tmp_path / "not-ours"
    not_ours.mkdir()
    with pytest.raises(ConfigError, match=r"--checkpoint.*gaffer_model\.json"):
        load_model(not_ours)


def test_bad_example_and_config_values_name_the_argument(tmp_path, model_dir) -> None:
    with pytest.raises(DatasetError, match="--example"):
        run_demo(DemoConfig(out=tmp_path / "o", checkpoint=model_dir, example=tmp_path))
    with pytest.raises(ConfigError, match="--frames"):
        DemoConfig(out=tmp_path, frames=-1)
    with pytest.raises(ConfigError, match="--batch-size"):
        DemoConfig(out=tmp_path, batch_size=0)
    assert DemoConfig(out=tmp_path).dtype == "auto"


def test_report_escapes_its_text() -> None:
    s = ImageScores(psnr=20.0, ssim=0.5, perceptual=None)
    row = LightingRow(
        key="000_x",
        label="<script>alert(1)</script>",
        world="lighting/a b.png",
        ldr="l.png",
        hdr="h.png",
        input="i.png",
        relit="r.png",
        ground_truth=None,
        scores=(("relit", s),),
    )
    content = ReportContent(
        title="t & u",
        settings=(("k", "<v>"),),
        timings=(("total", "1 s"),),
        perceptual_label="perceptual (n/a)",
        perceptual_note=None,
        means=(("relit", s),),
        rows=(row,),
        turntable_gif=None,
        turntable_label=None,
        created_utc="now",
    )
    page = render_html(content)
    assert "<script>" not in page and "&lt;script&gt;" in page and "t &amp; u" in page
    assert "lighting/a b.png" in image_links(page)
    assert "n/a" in page and "no render" in page


def _gaffer_tiny_present() -> bool:
    from gaffer_diffusion.pretrained import gaffer_tiny_path

    return (gaffer_tiny_path() / MANIFEST_NAME).is_file()


def _relight_args(tmp_path: Path) -> list[str]:
    from gaffer_envmap import EnvironmentMap, write_envmap

    rgba = np.zeros((40, 30, 4), np.uint8)
    rgba[..., :3] = 120
    rgba[8:30, 5:25, 3] = 255
    Image.fromarray(rgba).save(tmp_path / "obj.png")
    env = np.full((8, 16, 3), 0.5, np.float32)
    write_envmap(tmp_path / "env.exr", EnvironmentMap(radiance_linear=env))
    return ["relight", str(tmp_path / "obj.png"), "--envmap", str(tmp_path / "env.exr")]


def test_relight_and_demo_without_checkpoint_use_gaffer_tiny_stand_in(
    tmp_path, model_dir, example, monkeypatch, caplog
) -> None:
    """The wiring, with a random `tiny` model standing in for the shipped weights (and recording
    the shipped gaffer-tiny's sampling, which every command reads from the folder)."""
    from gaffer_diffusion import pretrained
    from gaffer_diffusion.suggested import read_default_sampling

    shipped = read_default_sampling(pretrained.gaffer_tiny_path())
    model_dir = save_pretrained(tiny_model(), tmp_path / "stand-in", suggested=shipped)
    monkeypatch.setattr(pretrained, "gaffer_tiny_path", lambda: model_dir)
    args = [*_relight_args(tmp_path), "--azimuth", "30", "--elevation", "10"]
    with caplog.at_level(logging.INFO, logger="gaffer_diffusion"):
        assert main([*args, "--out", str(tmp_path / "out.png"), "--steps", "1"]) == 0
    assert "using gaffer-tiny" in caplog.text and str(model_dir) in caplog.text
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="gaffer_diffusion"):
        result = run_demo(
            DemoConfig(out=tmp_path / "d", example=example, frames=0, extra_hdris=False)
        )
    assert "using gaffer-tiny" in caplog.text
    settings = json.loads(result.metrics_json.read_text())["settings"]
    assert settings["model"] == "gaffer-tiny"
    assert settings["num_inference_steps"] == shipped.num_inference_steps == 1
    assert settings["guidance_scale"] == shipped.guidance_scale == 1.0


@pytest.mark.skipif(not _gaffer_tiny_present(), reason="gaffer-tiny weights not in the package yet")
def test_relight_without_checkpoint_uses_gaffer_tiny(tmp_path, caplog) -> None:
    args = [*_relight_args(tmp_path), "--azimuth", "30", "--elevation", "10"]
    with caplog.at_level(logging.INFO, logger="gaffer_diffusion"):
        out = ["--out", str(tmp_path / "out.png"), "--steps", "1", "--output-size", "model"]
        assert main([*args, *out]) == 0
    assert "using gaffer-tiny" in caplog.text
    with Image.open(tmp_path / "out.png") as im:
        assert im.size == (128, 128)  # gaffer-tiny's resolution


def test_relight_without_checkpoint_names_the_missing_weights(
    tmp_path, monkeypatch, capsys
) -> None:
    from gaffer_diffusion import pretrained

    missing = tmp_path / "gaffer-tiny"
    monkeypatch.setattr(pretrained, "gaffer_tiny_path", lambda: missing)
    looked_for = str(missing / MANIFEST_NAME)
    args = [*_relight_args(tmp_path), "--azimuth", "30", "--elevation", "10"]
    assert main([*args, "--out", str(tmp_path / "out.png")]) == 2
    err = capsys.readouterr().err
    assert "gaffer-tiny" in err and looked_for in err and "--checkpoint" in err
    with pytest.raises(CheckpointNotFoundError, match="gaffer-tiny"):
        load_model(None)


def _strict_json(text: str) -> object:
    """`json.loads` that refuses `Infinity`/`NaN` (what strict parsers do) instead of reading them."""

    def refuse(constant: str) -> None:
        raise ValueError(f"non-standard JSON constant {constant}")

    return json.loads(text, parse_constant=refuse)


def test_metrics_json_is_strict_json(demo_out) -> None:
    m = _strict_json((demo_out / "metrics.json").read_text())
    assert isinstance(m, dict) and "summary" in m


@pytest.mark.parametrize("failure", [RuntimeError("simulated failure"), KeyboardInterrupt()])
def test_a_failed_rerun_leaves_the_earlier_folder_as_it_was(
    tmp_path, model_dir, example, monkeypatch, failure
) -> None:
    """The demo folder is complete or absent; a rerun that fails (an error, Ctrl-C) while
    writing leaves the earlier run's files untouched, and a finished rerun leaves none of them."""
    from gaffer_diffusion.demo import run as demo_run  # run_demo looks render_html up there

    out = tmp_path / "out"
    cfg = {"checkpoint": model_dir, "example": example, "num_inference_steps": 2}
    run_demo(DemoConfig(out=out, frames=2, extra_hdris=False, **cfg))
    (out / "envmap").mkdir()  # another tool's output in the same folder (nox demo: gaffer-envmap)
    (out / "envmap" / "keep.txt").write_text("gaffer-envmap demo")

    def files() -> dict[str, bytes]:
        return {str(p.relative_to(out)): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    before = files()

    def fail(*args, **kwargs):
        raise failure

    monkeypatch.setattr(demo_run, "render_html", fail)  # the last file written
    with pytest.raises(type(failure)):
        run_demo(DemoConfig(out=out, frames=0, extra_hdris=False, **cfg))
    assert files() == before
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # no staging folder left behind
    monkeypatch.undo()
    run_demo(DemoConfig(out=out, frames=0, extra_hdris=False, **cfg))
    assert not (out / "turntable").exists() and not (out / "turntable.gif").exists()  # not stale
    assert (out / "envmap" / "keep.txt").read_text() == "gaffer-envmap demo"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
