"""The whole chain through the four command lines, on disk artifacts only.

gaffer-data render (Cycles, 32 px) -> gaffer-diffusion train (a few steps of the `tiny` preset on that
render) -> export -> relight one rendered view with the trained model -> gaffer-data render-multiview ->
gaffer-nerf fit -> relight with the trained model -> evaluate. Every stage is a real CLI in a subprocess
that reads only what the stage before it wrote; the assertions are on those files (manifests, logs,
images, reports). About 1-2 minutes on 2 cores.
"""

import importlib.util
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

# The renderer runs in Blender worker subprocesses; this process never imports bpy (as gaffer-data's tests).
if importlib.util.find_spec("bpy") is None:
    pytest.skip(
        "bpy is not installed (gaffer-data[render]): the chain starts with a Cycles render",
        allow_module_level=True,
    )
for _module, _extra in (
    ("gaffer_data", "gaffer-data"),
    ("gaffer_diffusion", "gaffer-diffusion"),
    ("accelerate", "gaffer-diffusion[train]"),
    ("gaffer_nerf", "gaffer-nerf"),
):
    if importlib.util.find_spec(_module) is None:
        pytest.skip(f"{_module} is not installed ({_extra})", allow_module_level=True)

pytestmark = [pytest.mark.slow, pytest.mark.blender]

# Linear RGB of the constant environment maps: the lightings differ in colour, so relighting shows.
COLORS = {"red": (1.0, 0.05, 0.05), "blue": (0.05, 0.05, 1.0), "white": (0.8, 0.8, 0.8)}
SIZE = 32
VIEWS, LIGHTINGS = 2, 2
TRAIN_STEPS = 4
TRAIN_VIEWS, TEST_VIEWS = 6, 2
TINY_RENDER = [
    "--resolution", str(SIZE), "--samples", "4", "--no-denoise", "--world-map-resolution", "64",
    "--workers", "1", "--no-progress",
]  # fmt: skip


def _env() -> dict[str, str]:
    # Tiny tensors on shared cores: one intra-op thread is many times faster than contending ones.
    env = dict(os.environ)
    env.update(
        OMP_NUM_THREADS="1",
        MKL_NUM_THREADS="1",
        OPENBLAS_NUM_THREADS="1",
        HF_HUB_OFFLINE="1",
        TRANSFORMERS_OFFLINE="1",
        PYTHONHASHSEED="0",
    )
    return env


def _cli(module: str, *args: str | Path, timeout: float = 300) -> str:
    """Run `python -m MODULE ARGS` and return its stdout; fail with the tail of stderr."""
    cmd = [sys.executable, "-m", module, *map(str, args)]
    t0 = time.perf_counter()
    result = subprocess.run(
        cmd, capture_output=True, text=True, timeout=timeout, env=_env(), check=False
    )
    seconds = time.perf_counter() - t0
    print(f"{seconds:6.1f} s  {module} {args[0]}")
    assert result.returncode == 0, (
        f"`{' '.join(cmd)}` exited {result.returncode}:\n{result.stderr[-3000:]}"
    )
    return result.stdout


def _rgba(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        assert im.mode == "RGBA", (path, im.mode)
        return np.asarray(im, dtype=np.float64) / 255.0


def _finite(values: list[float]) -> bool:
    return bool(values) and all(isinstance(v, float) and math.isfinite(v) for v in values)


def test_render_train_relight_multiview_fit_relight_evaluate(tmp_path: Path) -> None:
    from gaffer_data.dataset import open_dataset, read_object
    from gaffer_data.testing import write_cube_obj, write_uniform_envmaps, write_uv_sphere_obj

    t_start = time.perf_counter()
    # -- inputs: two meshes and three constant-colour maps -----------------------------------------
    objects, envmaps = tmp_path / "objects", tmp_path / "envmaps"
    write_uv_sphere_obj(objects / "sphere.obj")
    write_cube_obj(objects / "cube.obj")
    write_uniform_envmaps(envmaps, COLORS)

    # -- 1. gaffer-data render ----------------------------------------------------------------------
    render = tmp_path / "render"
    _cli(
        "gaffer_data.cli", "render", "--objects", objects, "--envmaps", envmaps, "--out", render,
        "--views", str(VIEWS), "--lightings", str(LIGHTINGS), *TINY_RENDER,
    )  # fmt: skip
    dataset_json = json.loads((render / "dataset.json").read_text())
    assert dataset_json["schema"] == "gaffer.render_dataset"
    assert sorted(dataset_json["objects"]) == ["cube", "sphere"] and dataset_json["failures"] == []
    ds = open_dataset(render)
    assert sorted(ds.object_ids) == ["cube", "sphere"]
    for oid in ds.object_ids:
        obj = read_object(ds.object(oid).root, verify=True)  # every file against its sha256
        assert len(obj.views) == VIEWS
        for view in obj.views:
            assert len(view.lit) == LIGHTINGS
            assert {li.envmap.name for li in view.lit} <= set(COLORS)
            for li in view.lit:
                assert _rgba(ds.object(oid).root / li.png).shape == (SIZE, SIZE, 4)

    # -- 2. gaffer-diffusion train: the tiny preset, a few steps on the render ---------------------
    run = tmp_path / "train"
    config = {
        "output_dir": str(run),
        "model": {"init": "preset", "preset": "tiny", "resolution": SIZE, "seed": 0},
        "data": {"root": str(render), "val_objects": 1, "envmap_height": 8, "num_workers": 0},
        "optim": {"lr": 1e-3, "warmup_steps": 2},
        "train": {
            "max_steps": TRAIN_STEPS,
            "batch_size": 2,
            "mixed_precision": "no",
            "gradient_checkpointing": False,
            "ema_decay": 0.9,
        },
        "checkpoint": {"every_steps": 2, "keep": 2},
        "logging": {"every_steps": 1, "progress_bar": False, "tensorboard": False},
        "validation": {"every_steps": 0},
    }
    config_path = tmp_path / "train.json"
    config_path.write_text(json.dumps(config, indent=2))
    out = _cli("gaffer_diffusion.cli", "train", "--config", config_path)
    assert f"-> {TRAIN_STEPS} (max_steps)" in out, out
    rows = [json.loads(line) for line in (run / "logs" / "train.jsonl").read_text().splitlines()]
    train_rows = [r for r in rows if r.get("kind", "train") == "train"]
    assert [r["step"] for r in train_rows] == list(range(1, TRAIN_STEPS + 1))
    assert _finite([r["loss"] for r in train_rows]) and _finite(
        [r["grad_norm"] for r in train_rows]
    )
    checkpoints = sorted(p.name for p in (run / "checkpoints").iterdir())
    assert checkpoints == ["checkpoint-00000002", f"checkpoint-{TRAIN_STEPS:08d}"], checkpoints
    final = run / "final"
    card = json.loads((final / "gaffer_model.json").read_text())
    assert card["schema"] == "gaffer.diffusion_model" and card["config"]["resolution"] == SIZE

    # -- 2b. gaffer-diffusion export: the last checkpoint's EMA weights are the final model's -------
    exported = tmp_path / "exported"
    _cli("gaffer_diffusion.cli", "export", run / "checkpoints" / checkpoints[-1], "--out", exported)
    from safetensors.numpy import load_file

    unet_file = Path("unet") / "diffusion_pytorch_model.safetensors"
    a, b = load_file(exported / unet_file), load_file(final / unet_file)
    assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
    # --half: the same weights rounded to float16 in a file of half the size; they load as float32
    halved = tmp_path / "exported-half"
    _cli("gaffer_diffusion.cli", "export", run / "checkpoints" / checkpoints[-1], "--out", halved, "--half")  # fmt: skip
    h = load_file(halved / unet_file)
    assert h.keys() == a.keys() and all(h[k].dtype == np.float16 for k in h)
    assert all(np.array_equal(h[k], a[k].astype(np.float16)) for k in h)
    assert (halved / unet_file).stat().st_size < 0.6 * (exported / unet_file).stat().st_size
    import torch

    from gaffer_diffusion.loading import load_pretrained

    loaded = load_pretrained(halved).model.unet
    assert all(p.dtype == torch.float32 for p in loaded.parameters())
    k0 = next(iter(h))
    np.testing.assert_array_equal(loaded.state_dict()[k0].numpy(), h[k0].astype(np.float32))
    # the encoding and framing it was trained with travel with the weights (relight below has no
    # --compat: before, a self-trained model was relit with the authors' encoding unless told)
    for folder in (final, exported):
        own = json.loads((folder / "gaffer_model.json").read_text())["suggested_sampling"]
        assert own["compat"] == "default", own

    # -- 3. gaffer-diffusion relight: one rendered view under another map, with the exported model --
    sphere = ds.object("sphere").root
    view0 = read_object(sphere).views[0]
    image = sphere / view0.lit[0].png
    cameras = np.load(sphere / "cameras.npz")
    w2c = tmp_path / "w2c.npy"
    np.save(w2c, cameras["w2c_blender"][0])
    target = next(n for n in COLORS if n != view0.lit[0].envmap.name)
    relit = tmp_path / "relit.png"
    _cli(
        "gaffer_diffusion.cli", "relight", image, "--envmap", envmaps / f"{target}.exr",
        "--w2c", w2c, "--checkpoint", exported, "--steps", "2",
        "--guidance", "1", "--seed", "0", "--device", "cpu", "--out", relit,
    )  # fmt: skip
    before, after = _rgba(image), _rgba(relit)
    assert after.shape == before.shape == (SIZE, SIZE, 4)
    inside = before[..., 3] > 0.5
    assert inside.sum() > 50
    assert np.abs(after[inside, :3] - before[inside, :3]).mean() > 1e-3  # the object changed
    outside = before[..., 3] == 0
    np.testing.assert_array_equal(after[outside], before[outside])  # the background is kept
    np.testing.assert_array_equal(after[..., 3], before[..., 3])

    # -- 4. gaffer-data render-multiview: the sphere, train/test splits, shared lightings -----------
    mv_objects = tmp_path / "mv_objects"
    write_uv_sphere_obj(mv_objects / "sphere.obj")
    multiview = tmp_path / "multiview"
    _cli(
        "gaffer_data.cli", "render-multiview", "--objects", mv_objects, "--envmaps", envmaps,
        "--out", multiview, "--train-views", str(TRAIN_VIEWS), "--test-views", str(TEST_VIEWS),
        "--lightings", "2", "--no-flip", "--yaw-steps", "1", *TINY_RENDER,
    )  # fmt: skip
    mv_ds = open_dataset(multiview)
    assert list(mv_ds.object_ids) == ["sphere"]
    scene = mv_ds.object("sphere").root
    mv_obj = read_object(scene, verify=True)
    assert [len(mv_obj.split_views(s)) for s in ("train", "test")] == [TRAIN_VIEWS, TEST_VIEWS]
    for split, count in (("train", TRAIN_VIEWS), ("test", TEST_VIEWS)):
        frames = json.loads((scene / f"transforms_{split}.json").read_text())["frames"]
        assert len(frames) == count
        assert all(np.asarray(f["transform_matrix"]).shape == (4, 4) for f in frames)
    # the lighting names of lighting 0 and 1, shared by every view
    lightings = {li.lighting_index: li.envmap.name for li in mv_obj.views[0].lit}
    assert all(
        {li.lighting_index: li.envmap.name for li in v.lit} == lightings for v in mv_obj.views
    )

    # -- 5. gaffer-nerf fit under lighting 0 ---------------------------------------------------------
    field = tmp_path / "field"
    _cli(
        "gaffer_nerf.cli", "fit", scene, "--out", field, "--preset", "tiny", "--iterations", "40",
        "--batch-rays", "512", "--lighting-index", "0", "--seed", "0", "--device", "cpu",
        "--no-progress",
    )  # fmt: skip
    assert (field / "field.safetensors").is_file() and (field / "config.json").is_file()
    fit_report = json.loads((field / "fit_report.json").read_text())
    assert fit_report["iterations_run"] == 40

    # -- 6. gaffer-nerf relight to lighting 1 with the trained diffusion model ----------------------
    relit_field = tmp_path / "relit_field"
    _cli(
        "gaffer_nerf.cli", "relight", field, "--data", scene, "--input-lighting", "0",
        "--target-lighting", "1", "--checkpoint", final, "--compat", "default", "--out",
        relit_field, "--preset", "tiny", "--stage1-iterations", "10", "--stage2-iterations", "2",
        "--steps", "2", "--guidance", "1", "--device", "cpu", "--no-progress",
    )  # fmt: skip
    assert (relit_field / "field.safetensors").is_file()
    report = json.loads((relit_field / "relight_report.json").read_text())
    assert report["model"]["source"] == str(final)
    stage1, stage2 = report["report"]["stage1"], report["report"]["stage2"]
    assert stage1["iterations"] == 10 and _finite(stage1["losses"]) and len(stage1["losses"]) == 10
    assert stage2["iterations"] == 2 and _finite(stage2["losses"]) and len(stage2["losses"]) == 2
    relit_views = sorted((relit_field / "relit_views").glob("*.png"))
    assert len(relit_views) == TRAIN_VIEWS
    with Image.open(relit_views[0]) as im:
        assert im.size == (SIZE, SIZE)

    # -- 7. gaffer-nerf evaluate against the held-out views under lighting 1 -----------------------
    metrics_path, pred = tmp_path / "metrics.json", tmp_path / "pred"
    _cli(
        "gaffer_nerf.cli", "evaluate", relit_field, "--data", scene, "--target-lighting", "1",
        "--split", "test", "--json", metrics_path, "--pred-dir", pred, "--device", "cpu",
        "--no-progress",
    )  # fmt: skip
    metrics = json.loads(metrics_path.read_text())
    assert len(metrics["items"]) == TEST_VIEWS
    psnrs = [metrics["mean_raw"]["psnr"], *(item["raw"]["psnr"] for item in metrics["items"])]
    assert _finite(psnrs) and all(5.0 < p < 100.0 for p in psnrs), psnrs
    assert 0.0 < metrics["mean_raw"]["ssim"] <= 1.0
    assert len(sorted(pred.glob("*.png"))) == TEST_VIEWS
    print(f"chain: {time.perf_counter() - t_start:.1f} s")
