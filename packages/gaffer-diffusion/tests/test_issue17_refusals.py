"""Refusal gaps: an all-black `--mask-dir` mask, `data.val_objects` >= the objects, and `--sanitize`
on `evaluate` and `demo` (the maps were read with a hard-coded "zero")."""

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from gaffer_diffusion.cli import main
from gaffer_diffusion.errors import GafferDiffusionError


def _write(folder: Path, name: str, arr: np.ndarray) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    Image.fromarray(arr).save(folder / name)


def test_an_all_black_mask_is_refused_not_scored(tmp_path: Path, capsys) -> None:
    rng = np.random.default_rng(0)
    for name in ("a.png", "b.png"):
        _write(tmp_path / "pred", name, rng.integers(0, 255, (16, 16, 3), dtype=np.uint8))
        _write(tmp_path / "gt", name, rng.integers(0, 255, (16, 16, 3), dtype=np.uint8))
    _write(tmp_path / "mask", "a.png", np.zeros((16, 16), np.uint8))  # all black
    _write(tmp_path / "mask", "b.png", np.full((16, 16), 255, np.uint8))
    out = tmp_path / "scores.json"
    argv = ["evaluate", "--pred", str(tmp_path / "pred"), "--gt", str(tmp_path / "gt")]
    argv += ["--mask-dir", str(tmp_path / "mask"), "--no-perceptual", "--json", str(out)]
    assert main(argv) == 2  # it scored "object mask" PSNR nan / SSIM 0.0 and exited 0
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "`--mask-dir`" in err and "1 of 2 masks are all black" in err and "a.png" in err
    assert not out.exists()
    _write(tmp_path / "mask", "a.png", np.full((16, 16), 255, np.uint8))  # fixed: scored
    assert main(argv) == 0 and json.loads(out.read_text())["items"][0]["name"] == "a.png"


def test_val_objects_not_below_the_object_count_is_refused_before_training(
    tmp_path: Path, capsys
) -> None:
    from gaffer_diffusion.training.testing import write_synthetic_dataset

    root = write_synthetic_dataset(tmp_path / "d", objects=2, views=1, lightings=3)
    raw = {  # the sections of `training.testing.tiny_train_config`
        "output_dir": str(tmp_path / "run"),
        "model": {"init": "preset", "preset": "tiny", "resolution": 32},
        "data": {"root": str(root), "val_objects": 1, "envmap_height": 8},
        "optim": {"lr": 1e-3, "warmup_steps": 2},
        "train": {"max_steps": 2, "batch_size": 2, "mixed_precision": "no"},
        "logging": {"every_steps": 1, "progress_bar": False, "tensorboard": False},
        "validation": {"every_steps": 0},
    }
    raw["data"]["val_objects"] = 2
    config = tmp_path / "train.json"
    config.write_text(json.dumps(raw))
    assert main(["train", "--config", str(config)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "`data.val_objects` is 2" in err and "holds 2 object" in err and "at most 1" in err
    assert not list((tmp_path / "run").glob("checkpoint-*"))  # no step was taken


def _exr(path: Path, radiance: np.ndarray) -> Path:
    from gaffer_envmap.io import write_envmap

    write_envmap(path, radiance.astype(np.float32))
    return path


def test_evaluate_checks_the_maps_with_sanitize_before_the_model_loads(tmp_path: Path) -> None:
    from gaffer_diffusion.cli.evaluate import _check_envmaps

    clean = np.full((8, 16, 3), 0.5, np.float32)
    nan = clean.copy()
    nan[2, 3, 0] = np.nan
    inf = clean.copy()
    inf[1, 1, :] = np.inf
    maps = {n: _exr(tmp_path / f"{n}.exr", a) for n, a in (("c", clean), ("n", nan), ("i", inf))}

    def pairs(*names: str) -> list:
        return [SimpleNamespace(lighting=SimpleNamespace(source=maps[n])) for n in names]

    _check_envmaps(pairs("c", "c"), "strict")  # clean: every policy passes
    for policy in ("raise", "strict"):
        with pytest.raises(GafferDiffusionError, match="--sanitize zero") as info:
            _check_envmaps(pairs("c", "n"), policy)
        assert "1 NaN" in str(info.value) and f"`--sanitize {policy}` refused it" in str(info.value)
    _check_envmaps(pairs("n", "i"), "zero")  # what the scoring does with them
    _check_envmaps(pairs("n"), "clamp")  # no +Inf: clamp == zero
    with pytest.raises(GafferDiffusionError, match=r"\+Inf"):  # scored differently than asked
        _check_envmaps(pairs("i"), "clamp")


def test_demo_reads_the_examples_maps_with_sanitize(tmp_path: Path) -> None:
    from gaffer_diffusion.demo.config import DemoConfig
    from gaffer_diffusion.demo.lightings import _Envmaps
    from gaffer_diffusion.evaluation import EnvmapLighting

    radiance = np.full((8, 16, 3), 0.5, np.float32)
    radiance[0, 0, 0] = -0.4  # a substantial negative
    lt = EnvmapLighting(
        source=_exr(tmp_path / "m.exr", radiance),
        flip=False,
        yaw_step=0,
        num_steps=1,
        strength=1.0,
        w2c_blender=np.eye(4)[:3],
    )
    with pytest.raises(GafferDiffusionError, match="--sanitize zero") as info:
        _Envmaps().get(lt)  # the default, "raise", refuses it (it was zeroed silently)
    assert "`--sanitize raise` refused it" in str(info.value)
    assert float(np.asarray(_Envmaps("zero").get(lt).radiance_linear).min()) == 0.0
    assert DemoConfig(out=tmp_path / "o").sanitize == "raise"
    with pytest.raises(SystemExit):  # argparse: not one of the choices
        main(["demo", "--out", str(tmp_path / "o"), "--sanitize", "never"])
