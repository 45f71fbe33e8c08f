"""`evaluate --dataset`: a tiny random model over a tiny gaffer-data dataset written without Blender."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

pytest.importorskip("gaffer_data")
pytest.importorskip("gaffer_envmap.encode")

from gaffer_diffusion.cli import main
from gaffer_diffusion.errors import ConfigError, DatasetError
from gaffer_diffusion.evaluation import (
    EvaluationConfig,
    dataset_pairs,
    evaluate_dataset,
    pair_lighting,
)
from gaffer_diffusion.metrics import combine_reports, evaluate_images
from gaffer_diffusion.pipelines import RelightPipeline, SamplingConfig
from gaffer_diffusion.testing import tiny_model

RES = 32  # renders at half the tiny model's 64 px: evaluation resizes them


def _write_envmaps(folder: Path) -> dict[str, Path]:
    from gaffer_envmap import EnvironmentMap, write_envmap

    folder.mkdir(parents=True, exist_ok=True)
    maps = {"warm": (1.0, 0.6, 0.3), "cool": (0.2, 0.4, 1.0)}
    out = {}
    for k, (name, rgb) in enumerate(maps.items()):
        env = np.broadcast_to(np.asarray(rgb, np.float32), (8, 16, 3)).copy()
        env[2, 3 + 5 * k] = 50.0  # a small sun, at a different place per map
        write_envmap(folder / f"{name}.exr", EnvironmentMap(radiance_linear=env))
        out[name] = folder / f"{name}.exr"
    return out


def write_tiny_dataset(
    root: Path, envmaps: dict[str, Path], *, views: int = 2, duplicate_last: bool = False
) -> Path:
    """A gaffer-data dataset with one object, `views` views x 3 lightings of flat-shaded PNGs.

    Written by gaffer-data's own fake-dataset writer (`gaffer_data.testing.write_fake_object`, no
    Blender): the images are a disc whose colour is the map's colour, so lighting changes are visible
    and the reader sees a complete object.
    """
    from gaffer_data.dataset import (
        CameraSample,
        EnvmapRef,
        Intrinsics,
        LitImage,
        ObjectPlan,
        ViewRecord,
        sha256_file,
    )
    from gaffer_data.testing import tiny_config, write_fake_object
    from gaffer_envmap.poses import orbit_w2c_blender

    config = tiny_config(views=views, lightings=3, resolution=RES)
    obj = root / "objects" / "disc"
    yy, xx = np.mgrid[:RES, :RES]
    alpha = (((yy - RES / 2) ** 2 + (xx - RES / 2) ** 2) < (RES / 3) ** 2).astype(np.uint8) * 255
    names = list(envmaps)
    view_records, w2c = [], []
    pngs: dict[str, np.ndarray] = {}
    for v in range(views):
        az, el = 40.0 * v, 15.0
        w2c.append(orbit_w2c_blender(az, el, 2.0).matrix)
        lit = []
        for li in range(3):
            # duplicate_last: lighting 2 is drawn exactly as lighting 0 (a repeated draw)
            same = duplicate_last and li == 2
            name = names[0 if same else li % len(names)]
            ref = EnvmapRef(
                name=name,
                source=str(envmaps[name]),
                source_sha256=sha256_file(envmaps[name]),
                flip=li == 2 and not same,
                yaw_step=0 if same else li,
                num_steps=4,
            )
            rgba = np.zeros((RES, RES, 4), np.uint8)
            rgba[..., :3] = (np.array([60, 120, 200]) + 40 * li + 10 * v) % 256
            rgba[..., 3] = alpha
            png = f"lit/{v:03d}_{li:03d}.png"
            pngs[png] = rgba
            lit.append(LitImage(lighting_index=li, envmap=ref, exr=png, png=png))
        pngs[f"alpha/{v:03d}.png"] = alpha
        cam = CameraSample(elevation_deg=el, azimuth_deg=az, distance=2.0, position=(0.0, 0.0, 0.0))
        view_records.append(
            ViewRecord(index=v, camera=cam, lit=tuple(lit), area=None, alpha=f"alpha/{v:03d}.png")
        )
    w2c_arr = np.stack(w2c)
    c2w_cv = np.stack([np.linalg.inv(np.vstack([m, [0, 0, 0, 1]])) for m in w2c_arr])
    c2w_cv = c2w_cv @ np.diag([1.0, -1.0, -1.0, 1.0])
    plan = ObjectPlan(
        object_id="disc",
        source="disc.obj",
        views=tuple(view_records),
        intrinsics=Intrinsics(width=RES, height=RES, fx=35.0, fy=35.0, cx=RES / 2, cy=RES / 2),
        config=config,
    )
    write_fake_object(
        obj,
        plan,
        pngs=pngs,
        w2c_blender=w2c_arr,
        c2w_opencv=c2w_cv,
        intrinsics=np.array([[35.0, 0, RES / 2], [0, 35.0, RES / 2], [0, 0, 1]]),
    )
    return root


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> tuple[Path, Path]:
    base = tmp_path_factory.mktemp("evalds")
    envmaps = _write_envmaps(base / "envmaps")
    return write_tiny_dataset(base / "render", envmaps), base / "envmaps"


def test_pairs_cover_every_target_of_every_view(dataset) -> None:
    root, _ = dataset
    pairs = dataset_pairs(root)
    assert [p.name for p in pairs] == [
        "disc/000_000_to_001",
        "disc/000_000_to_002",
        "disc/001_000_to_001",
        "disc/001_000_to_002",
    ]
    assert (
        pairs[0].input_image.name == "000_000.png" and pairs[0].target_image.name == "000_001.png"
    )
    assert pairs[1].lighting.flip and pairs[1].lighting.yaw_step == 2
    assert pairs[2].lighting.w2c_blender.shape == (3, 4)
    assert len(dataset_pairs(root, input_lighting=2, limit=3)) == 3
    assert dataset_pairs(root, input_lighting=1)[0].name == "disc/000_001_to_000"


def test_pairs_errors_name_the_fix(dataset, tmp_path) -> None:
    root, envmaps = dataset
    with pytest.raises(DatasetError, match="no lighting 7"):
        dataset_pairs(root, input_lighting=7)
    with pytest.raises(DatasetError, match="area-light"):
        dataset_pairs(root, input_lighting="area")
    with pytest.raises(ConfigError, match="input_lighting"):
        dataset_pairs(root, input_lighting=-1)
    with pytest.raises(DatasetError, match="no \\(input, target\\) pair"):
        dataset_pairs(tmp_path)
    # the maps moved: the recorded paths fail, `envmap_dirs` finds them by name
    moved = tmp_path / "moved"
    moved.mkdir()
    for p in envmaps.iterdir():
        (moved / p.name).write_bytes(p.read_bytes())
    renamed = tmp_path / "ds"
    import shutil

    shutil.copytree(root, renamed)
    manifest = renamed / "objects" / "disc" / "manifest.json"
    manifest.write_text(manifest.read_text().replace(str(envmaps), str(tmp_path / "gone")))
    with pytest.raises(DatasetError, match="--envmaps"):
        dataset_pairs(renamed)
    pairs = dataset_pairs(renamed, envmap_dirs=[moved])
    assert pairs[0].lighting.source.parent == moved


def test_pair_lighting_is_the_rotated_augmented_map(dataset) -> None:
    from gaffer_envmap import AugmentSpec
    from gaffer_envmap.encode import encode_lighting
    from gaffer_envmap.io import read_envmap

    root, _ = dataset
    p = dataset_pairs(root)[1]
    maps = pair_lighting([p], 64, "neural-gaffer")
    lt = p.lighting
    env = AugmentSpec(flip=lt.flip, yaw_step=lt.yaw_step, num_steps=lt.num_steps).apply(
        read_envmap(lt.source)
    )
    ref = encode_lighting(env, lt.w2c_blender[None], size=64, compat="neural-gaffer")
    torch.testing.assert_close(maps.ldr, ref.ldr.float())
    torch.testing.assert_close(maps.hdr, ref.hdr.float())


def test_evaluate_dataset_is_batch_invariant_and_merges_reports(dataset, tmp_path) -> None:
    root, _ = dataset
    pairs = dataset_pairs(root)
    pipe = RelightPipeline(tiny_model())
    sampling = SamplingConfig(num_inference_steps=2)
    done = []
    a = evaluate_dataset(
        pipe,
        pairs,
        EvaluationConfig(sampling=sampling, batch_size=3, predictions_dir=tmp_path / "pred"),
        perceptual=None,
        settings={"checkpoint": "tiny"},
        on_batch=lambda d, n: done.append((d, n)),
    )
    b = evaluate_dataset(
        pipe, pairs, EvaluationConfig(sampling=sampling, batch_size=4), perceptual=None
    )
    assert done == [(3, 4), (4, 4)]
    assert [i.name for i in a.report.items] == [p.name for p in pairs]
    for x, y in zip(a.report.items, b.report.items, strict=True):
        assert x.raw.psnr == pytest.approx(y.raw.psnr, abs=1e-3)
    assert a.report.mean_aligned_mask is not None
    assert a.settings["checkpoint"] == "tiny" and a.settings["pairs"] == 4
    assert a.settings["num_inference_steps"] == 2 and a.settings["dtype"] == "float32"
    saved = sorted((tmp_path / "pred" / "disc").glob("*.png"))
    assert [s.stem for s in saved] == [p.name.split("/")[1] for p in pairs]
    # the saved PNGs are exactly what was scored (8-bit predictions)
    pred = torch.from_numpy(np.asarray(Image.open(saved[0]), np.float32) / 255).permute(2, 0, 1)
    # the target as evaluation reads it: the training loader (composited on white, then resized)
    from gaffer_diffusion.preprocess import load_rgba_on_white

    gt_t, _ = load_rgba_on_white(pairs[0].target_image, 64)
    single = evaluate_images(pred[None], gt_t[None], perceptual=None)
    assert single.mean_raw.psnr == pytest.approx(a.report.items[0].raw.psnr, abs=1e-4)
    md = a.to_markdown()
    assert "aligned (mask means)" in md and "num_inference_steps" in md
    assert json.loads(a.to_json())["metrics"]["items"][0]["name"] == pairs[0].name


def test_evaluate_dataset_scores_the_unrelit_input_baseline(dataset) -> None:
    root, _ = dataset
    pairs = dataset_pairs(root)
    pipe = RelightPipeline(tiny_model())
    sampling = SamplingConfig(num_inference_steps=1)
    on = evaluate_dataset(pipe, pairs, EvaluationConfig(sampling=sampling), perceptual=None)
    off = evaluate_dataset(
        pipe, pairs, EvaluationConfig(sampling=sampling, baselines=False), perceptual=None
    )
    assert off.baseline is None and "Baseline" not in off.to_markdown()
    assert on.baseline is not None and len(on.baseline.items) == len(pairs)
    # the baseline is the input image itself, scored like a prediction against the target
    from gaffer_diffusion.evaluation import _to_chw, read_rgba_on_white

    p = pairs[0]
    inp = _to_chw([read_rgba_on_white(p.input_image, 64)[0]])
    gt = _to_chw([read_rgba_on_white(p.target_image, 64)[0]])
    direct = evaluate_images(inp, gt, perceptual=None)
    assert on.baseline.items[0].raw.psnr == pytest.approx(direct.mean_raw.psnr, abs=1e-4)
    # the discs differ in colour only, so aligning the input's channels to the target must help
    assert on.baseline.mean_aligned_image.psnr > on.baseline.mean_raw.psnr
    doc = json.loads(on.to_json())
    assert doc["baseline_unrelit_input"]["items"][0]["name"] == pairs[0].name
    assert "Baseline, the unrelit input" in on.to_markdown()


def test_targets_lit_exactly_as_the_input_are_left_out(tmp_path) -> None:
    maps = _write_envmaps(tmp_path / "maps")
    root = write_tiny_dataset(tmp_path / "dup", maps, duplicate_last=True)
    pairs = dataset_pairs(root)
    # per view: lighting 1 stays, lighting 2 (the input's own draw repeated) is not a relighting task
    assert [p.target_lighting for p in pairs] == [1, 1]
    assert len(dataset_pairs(write_tiny_dataset(tmp_path / "ok", maps))) == 4


def test_combine_reports_means_over_all_items() -> None:
    g = torch.Generator().manual_seed(0)
    gt = torch.rand(3, 3, 16, 16, generator=g)
    pred = (gt + 0.1 * torch.rand(gt.shape, generator=g)).clamp(0, 1)
    whole = evaluate_images(pred, gt, perceptual=None)
    parts = [
        evaluate_images(pred[:1], gt[:1], perceptual=None),
        evaluate_images(pred[1:], gt[1:], perceptual=None),
    ]
    merged = combine_reports(parts)
    assert merged.mean_raw.psnr == pytest.approx(whole.mean_raw.psnr)
    assert merged.mean_aligned_image.ssim == pytest.approx(whole.mean_aligned_image.ssim)
    with pytest.raises(ConfigError, match="reports"):
        combine_reports([])
    masked = evaluate_images(pred[:1], gt[:1], mask=torch.ones(1, 1, 16, 16), perceptual=None)
    with pytest.raises(ConfigError, match="masked"):
        combine_reports([parts[0], masked])


def test_cli_evaluate_dataset_with_our_checkpoint(dataset, tmp_path, capsys) -> None:
    root, envmaps = dataset
    model = tmp_path / "model"
    assert main(["init-random", "--preset", "tiny", "--out", str(model)]) == 0
    args = ["evaluate", "--dataset", str(root), "--checkpoint", str(model), "--steps", "2"]
    args += ["--envmaps", str(envmaps), "--limit", "2", "--no-perceptual"]
    args += ["--json", str(tmp_path / "r.json"), "--markdown", str(tmp_path / "r.md")]
    assert main(args) == 0
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["settings"]["pairs"] == 2 and report["settings"]["checkpoint"] == str(model)
    assert len(report["metrics"]["items"]) == 2
    assert "aligned (whole image)" in (tmp_path / "r.md").read_text()
    assert "PSNR" in capsys.readouterr().out
    # --dataset and --pred are two different modes
    assert main(["evaluate", "--dataset", str(root), "--pred", str(tmp_path)]) == 2
    assert "either" in capsys.readouterr().err
    # without --checkpoint, evaluate now uses the shipped gaffer-tiny (not exercised here: its
    # weights are replaced separately); a bad --object-fraction is refused
    bad = ["evaluate", "--dataset", str(root), "--checkpoint", str(model), "--no-perceptual"]
    assert main([*bad, "--object-fraction", "1.5"]) == 2
    assert "object-fraction" in capsys.readouterr().err


def test_evaluation_config_validates() -> None:
    with pytest.raises(ConfigError, match="batch_size"):
        EvaluationConfig(batch_size=0)
    with pytest.raises(ConfigError, match="compat"):
        EvaluationConfig(compat="theirs")  # type: ignore[arg-type]
    assert dataclasses.replace(EvaluationConfig(), seed=3).seed == 3
    assert EvaluationConfig().object_fraction is None  # the authors' protocol: whole renders
    assert EvaluationConfig(object_fraction=0.75).object_fraction == 0.75
    assert EvaluationConfig(object_fraction=1.0).object_fraction == 1.0
    for bad in (0.0, 1.5, -0.25):
        with pytest.raises(ConfigError, match="object_fraction"):
            EvaluationConfig(object_fraction=bad)


def test_evaluate_dataset_keeps_the_input_background_by_default(dataset, tmp_path) -> None:
    root, _ = dataset
    pairs = dataset_pairs(root)[:2]
    pipe = RelightPipeline(tiny_model())
    sampling = SamplingConfig(num_inference_steps=1)
    kept = evaluate_dataset(
        pipe,
        pairs,
        EvaluationConfig(sampling=sampling, predictions_dir=tmp_path / "kept"),
        perceptual=None,
    )
    full = evaluate_dataset(
        pipe,
        pairs,
        EvaluationConfig(
            sampling=sampling, predictions_dir=tmp_path / "full", keep_background=False
        ),
        perceptual=None,
    )
    from gaffer_diffusion.evaluation import read_rgba_on_white

    name = pairs[0].name.split("/")[1] + ".png"
    k = np.asarray(Image.open(tmp_path / "kept" / "disc" / name), np.float32) / 255
    f = np.asarray(Image.open(tmp_path / "full" / "disc" / name), np.float32) / 255
    x, alpha = read_rgba_on_white(pairs[0].input_image, 64)
    bg, fg = alpha == 0.0, alpha == 1.0
    assert bg.any() and fg.any()
    np.testing.assert_allclose(k[bg], x[bg], atol=1 / 255)  # background: the input's white
    assert np.abs(f[bg] - x[bg]).max() > 2 / 255  # the random model paints the background
    np.testing.assert_array_equal(k[fg], f[fg])  # object: the model's pixels either way
    assert kept.report.mean_raw.psnr > full.report.mean_raw.psnr
    assert kept.settings["background"] != full.settings["background"]


def test_evaluate_dataset_object_fraction_crops_input_target_and_mask(dataset) -> None:
    from gaffer_diffusion.evaluation import pair_crop_box, read_mask, read_rgba_on_white
    from gaffer_diffusion.preprocess import object_square, read_alpha

    root, _ = dataset
    pairs = dataset_pairs(root)[:2]
    p = pairs[0]
    assert pair_crop_box(p, None) is None
    box = pair_crop_box(p, 0.5)
    assert box == object_square(read_alpha(p.mask if p.mask is not None else p.input_image), 0.5)
    # the disc spans 2/3 of the render; at fraction 0.5 the square reaches past it (white, alpha 0)
    top, left, side = box
    assert side > RES and top < 0 and left < 0
    _, whole_alpha = read_rgba_on_white(p.input_image, 64)
    x, alpha = read_rgba_on_white(p.input_image, 64, box)
    assert alpha.mean() < whole_alpha.mean()  # zoomed out: the object covers less of the frame
    np.testing.assert_allclose(x[0, 0], 1.0, atol=1e-6)  # padding outside the render is white
    assert alpha[0, 0] == 0.0
    if p.mask is not None:
        np.testing.assert_allclose(read_mask(p.mask, 64, box), alpha, atol=2 / 255)
    pipe = RelightPipeline(tiny_model())
    sampling = SamplingConfig(num_inference_steps=1)
    whole = evaluate_dataset(pipe, pairs, EvaluationConfig(sampling=sampling), perceptual=None)
    cropped = evaluate_dataset(
        pipe, pairs, EvaluationConfig(sampling=sampling, object_fraction=0.5), perceptual=None
    )
    assert "whole render" in whole.settings["framing"]
    assert "0.5" in cropped.settings["framing"]
    assert cropped.report.mean_object_raw is not None
    assert cropped.report.mean_raw.psnr != pytest.approx(whole.report.mean_raw.psnr, abs=1e-3)
    assert cropped.summary().startswith("object mask: PSNR")
    assert json.loads(cropped.to_json())["closer_than_input"] is not None


def test_envmaps_with_the_right_names_but_other_pixels_are_refused(tmp_path, capsys) -> None:
    """Each manifest records the maps' sha256; `--envmaps` maps that differ are refused."""
    import shutil

    from gaffer_envmap import EnvironmentMap, write_envmap

    maps = _write_envmaps(tmp_path / "maps")
    root = write_tiny_dataset(tmp_path / "render", maps)
    moved = tmp_path / "moved"
    shutil.move(tmp_path / "maps", moved)  # the recorded paths no longer exist
    other = tmp_path / "other"
    shutil.copytree(moved, other)
    env = np.full((8, 16, 3), 0.5, np.float32)
    write_envmap(other / "warm.exr", EnvironmentMap(radiance_linear=env))  # same name, other map
    assert len(dataset_pairs(root, envmap_dirs=[moved])) > 0
    with pytest.raises(DatasetError, match=r"warm.*sha256.*--envmaps"):
        dataset_pairs(root, envmap_dirs=[other])
    args = ["evaluate", "--dataset", str(root), "--envmaps", str(other), "--no-perceptual"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "warm.exr" in err and "--envmaps" in err and len(err.strip().splitlines()) == 1
