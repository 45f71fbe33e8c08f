import json

import numpy as np
import pytest
import torch
from PIL import Image

from gaffer_diffusion.cli import main
from gaffer_diffusion.errors import InputValueError
from gaffer_diffusion.preprocess import load_object_image, prepare_object_image


def _rgba(h: int = 90, w: int = 60) -> np.ndarray:
    a = np.zeros((h, w, 4), np.uint8)
    a[..., :3] = 40
    a[20:50, 10:40, 3] = 255
    return a


def test_preprocess_crops_pads_to_75_percent_on_white() -> None:
    a = _rgba()
    prep = prepare_object_image(a[..., :3], a[..., 3], size=64)
    assert prep.image.shape == (1, 3, 64, 64) and prep.mask.shape == (1, 1, 64, 64)
    assert prep.bbox == (20, 10, 50, 40)
    cols = torch.nonzero(prep.mask[0, 0].amax(0) > 0.5).flatten()
    span = int(cols.max() - cols.min() + 1) / 64
    assert span == pytest.approx(0.75, abs=0.04)
    assert float(prep.image[0, :, 0, 0].min()) == 1.0  # white background
    assert float(prep.image[0, :, 32, 32].max()) == pytest.approx(40 / 255, abs=1e-6)


@pytest.mark.parametrize("shape", [(1, 1), (3, 700), (900, 20)], ids=["1px", "wide", "tall"])
def test_preprocess_tiny_and_non_square_inputs(shape) -> None:
    rgb = np.full((*shape, 3), 0.3, np.float32)
    alpha = np.ones(shape, np.float32)
    prep = prepare_object_image(rgb, alpha, size=32)
    assert prep.image.shape == (1, 3, 32, 32) and torch.isfinite(prep.image).all()


def test_preprocess_errors(tmp_path) -> None:
    a = _rgba()
    with pytest.raises(InputValueError, match="empty"):
        prepare_object_image(a[..., :3], np.zeros(a.shape[:2]), size=32)
    Image.fromarray(a[..., :3]).save(tmp_path / "rgb.png")
    with pytest.raises(InputValueError, match="--mask"):
        load_object_image(tmp_path / "rgb.png")
    Image.fromarray(a[..., 3]).save(tmp_path / "mask.png")
    prep = load_object_image(tmp_path / "rgb.png", mask_path=tmp_path / "mask.png", size=32)
    assert prep.image.shape == (1, 3, 32, 32)
    nan = np.full((4, 4, 3), np.nan, np.float32)
    with pytest.raises(InputValueError, match="NaN"):
        prepare_object_image(nan, np.ones((4, 4)), size=8)


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli") / "model"
    assert main(["init-random", "--preset", "tiny", "--out", str(d)]) == 0
    return d


def test_cli_relight_with_pre_encoded_maps(tmp_path, model_dir) -> None:
    Image.fromarray(_rgba()).save(tmp_path / "obj.png")
    maps = np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8)
    Image.fromarray(maps).save(tmp_path / "ldr.png")
    Image.fromarray(maps[::-1].copy()).save(tmp_path / "hdr.png")
    args = ["relight", str(tmp_path / "obj.png"), "--ldr", str(tmp_path / "ldr.png")]
    args += ["--hdr", str(tmp_path / "hdr.png"), "--checkpoint", str(model_dir)]
    args += ["--out", str(tmp_path / "out.png"), "--steps", "2", "--output-size", "model"]
    assert main(args) == 0
    out = np.asarray(Image.open(tmp_path / "out.png"))
    assert out.shape == (64, 64, 3) and out.dtype == np.uint8


def test_cli_relight_envmap_turntable(tmp_path, model_dir) -> None:
    pytest.importorskip("gaffer_envmap.encode")
    from gaffer_envmap import EnvironmentMap, write_envmap

    env = np.full((16, 32, 3), 0.2, np.float32)
    env[3, 5] = 1e5  # a sun
    write_envmap(tmp_path / "sun.exr", EnvironmentMap(radiance_linear=env))
    Image.fromarray(_rgba()).save(tmp_path / "obj.png")
    args = ["relight", str(tmp_path / "obj.png"), "--envmap", str(tmp_path / "sun.exr")]
    args += ["--azimuth", "30", "--elevation", "10", "--checkpoint", str(model_dir)]
    args += ["--out", str(tmp_path / "t.png"), "--steps", "2", "--turntable", "2"]
    assert main(args) == 0
    assert (tmp_path / "t_000.png").is_file() and (tmp_path / "t_001.png").is_file()
    assert (tmp_path / "t.gif").is_file()


def test_cli_errors_are_clear(tmp_path, model_dir, capsys) -> None:
    Image.fromarray(_rgba()[..., :3]).save(tmp_path / "rgb.png")
    for name in ("a.png", "b.png"):  # lighting maps that exist: the flags are checked first
        Image.fromarray(np.full((16, 16, 3), 128, np.uint8)).save(tmp_path / name)
    maps = ["--ldr", str(tmp_path / "a.png"), "--hdr", str(tmp_path / "b.png")]
    args = ["relight", str(tmp_path / "rgb.png"), *maps]
    args += ["--checkpoint", str(model_dir), "--out", str(tmp_path / "o.png")]
    # no alpha and no --mask: the mask is estimated; a flat grey picture has no object
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "no alpha channel, so its object mask" in err and "--mask MASK.png" in err
    assert err.count("\n") == 1 and not (tmp_path / "o.png").exists()
    assert not (tmp_path / "o.mask.png").exists()
    args = ["relight", str(tmp_path / "rgb.png"), *maps, "--checkpoint", str(tmp_path)]
    args += ["--out", str(tmp_path / "o.png")]
    assert main(args) == 2
    assert "--base-model" in capsys.readouterr().err


def test_cli_evaluate(tmp_path) -> None:
    rng = np.random.default_rng(0)
    (tmp_path / "p").mkdir()
    (tmp_path / "g").mkdir()
    for k in range(2):
        g = rng.integers(0, 255, (32, 32, 3), dtype=np.uint8)
        Image.fromarray(g).save(tmp_path / "g" / f"{k}.png")
        Image.fromarray((g * 0.8).astype(np.uint8)).save(tmp_path / "p" / f"{k}.png")
    args = ["evaluate", "--pred", str(tmp_path / "p"), "--gt", str(tmp_path / "g")]
    args += ["--json", str(tmp_path / "r.json"), "--markdown", str(tmp_path / "r.md")]
    assert main(args) == 0
    report = json.loads((tmp_path / "r.json").read_text())
    assert [i["name"] for i in report["items"]] == ["0.png", "1.png"]
    assert "aligned (whole image)" in (tmp_path / "r.md").read_text()


def test_turntable_frames_are_complete_or_absent(tmp_path, model_dir, monkeypatch) -> None:
    """A turntable that fails while writing leaves an earlier run's frames as they were;
    one that finishes leaves none of the earlier run's extra frames (fewer frames, other format)."""
    pytest.importorskip("gaffer_envmap.encode")
    from gaffer_diffusion import _video

    Image.fromarray(_rgba()).save(tmp_path / "obj.png")
    args = ["relight", str(tmp_path / "obj.png"), "--envmap", "studio", "--azimuth", "30"]
    args += ["--elevation", "10", "--checkpoint", str(model_dir), "--steps", "1"]
    args += ["--out", str(tmp_path / "t.png"), "--video", "gif"]
    for k in range(5):  # an earlier run of 5 frames
        (tmp_path / f"t_{k:03d}.png").write_bytes(b"old")
    (tmp_path / "t.gif").write_bytes(b"old")
    (tmp_path / "t_notes.txt").write_text("not a frame")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}

    def fail(*a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(_video, "write_animation", fail)
    assert main([*args, "--turntable", "3"]) == 2
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before  # and no staging folder
    monkeypatch.undo()
    assert main([*args, "--turntable", "3"]) == 0
    frames = sorted(p.name for p in tmp_path.glob("t_*.png"))
    assert frames == ["t_000.png", "t_001.png", "t_002.png"]
    assert (tmp_path / "t.gif").read_bytes()[:3] == b"GIF"
    assert (tmp_path / "t_notes.txt").is_file()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
