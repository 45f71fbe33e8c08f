"""`relight DIR --envmaps DIR` (batched grid with a progress bar) and turntable animations."""

import os
import stat
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from gaffer_diffusion import _video
from gaffer_diffusion._video import mp4_encoder, write_animation
from gaffer_diffusion.cli import main
from gaffer_diffusion.errors import ConfigError, MissingDependencyError


def _rgba(shade: int) -> np.ndarray:
    a = np.zeros((40, 30, 4), np.uint8)
    a[..., :3] = shade
    a[8:30, 5:25, 3] = 255
    return a


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("grid") / "model"
    assert main(["init-random", "--preset", "tiny", "--out", str(d)]) == 0
    return d


@pytest.fixture(scope="module")
def envmaps(tmp_path_factory) -> Path:
    pytest.importorskip("gaffer_envmap.encode")
    from gaffer_envmap import EnvironmentMap, write_envmap

    d = tmp_path_factory.mktemp("maps")
    for k, name in enumerate(("a", "b", "c")):
        env = np.full((8, 16, 3), 0.2 + 0.3 * k, np.float32)
        write_envmap(d / f"{name}.exr", EnvironmentMap(radiance_linear=env))
    (d / "notes.txt").write_text("ignored")
    return d


def test_relight_folder_x_envmaps_is_batched_and_batch_invariant(
    tmp_path, model_dir, envmaps, capsys
) -> None:
    imgs = tmp_path / "imgs"
    imgs.mkdir()
    for k in range(2):
        Image.fromarray(_rgba(40 + 80 * k)).save(imgs / f"obj{k}.png")
    common = [str(imgs), "--envmaps", str(envmaps), "--azimuth", "20", "--elevation", "5"]
    common += ["--checkpoint", str(model_dir), "--steps", "2"]
    assert main(["relight", *common, "--out", str(tmp_path / "o4"), "--batch-size", "4"]) == 0
    err = capsys.readouterr().err
    assert "6/6" in err  # the tqdm bar reached the end
    outs = sorted(
        p.relative_to(tmp_path / "o4").as_posix() for p in (tmp_path / "o4").rglob("*.png")
    )
    assert outs == [f"obj{i}/{m}.png" for i in range(2) for m in "abc"]
    assert main(["relight", *common, "--out", str(tmp_path / "o1"), "--batch-size", "1"]) == 0
    for rel in outs:
        a = np.asarray(Image.open(tmp_path / "o4" / rel), np.int16)
        b = np.asarray(Image.open(tmp_path / "o1" / rel), np.int16)
        assert np.abs(a - b).max() <= 1  # same seed per item: batching does not change results
    # a different map gives a different image
    a = np.asarray(Image.open(tmp_path / "o4" / "obj0/a.png"), np.int16)
    c = np.asarray(Image.open(tmp_path / "o4" / "obj0/c.png"), np.int16)
    assert np.abs(a - c).max() > 0


def test_relight_grid_errors(tmp_path, model_dir, envmaps, capsys) -> None:
    (tmp_path / "empty").mkdir()
    base = ["--checkpoint", str(model_dir), "--out", str(tmp_path / "o"), "--steps", "1"]
    pose = ["--azimuth", "0", "--elevation", "0"]
    assert main(["relight", str(tmp_path / "empty"), "--envmaps", str(envmaps), *pose, *base]) == 2
    assert "holds no images" in capsys.readouterr().err
    Image.fromarray(_rgba(50)).save(tmp_path / "x.png")
    args = ["relight", str(tmp_path / "x.png"), "--envmaps", str(envmaps), *pose, *base]
    assert main([*args, "--turntable", "3"]) == 2
    assert "--turntable" in capsys.readouterr().err
    assert main([*args, "--envmap", str(envmaps / "a.exr")]) == 2
    assert "not both" in capsys.readouterr().err
    assert main(["relight", str(tmp_path / "x.png"), "--envmaps", str(envmaps), *base]) == 2
    assert "--azimuth" in capsys.readouterr().err


def _frames(n: int = 3) -> list[np.ndarray]:
    return [np.full((9, 7, 3), 30 * k, np.uint8) for k in range(n)]


def test_animation_falls_back_to_gif_without_an_encoder(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(_video, "mp4_encoder", lambda: None)
    path = write_animation(_frames(), tmp_path / "t", fmt="auto", fps=10)
    assert path.suffix == ".gif"
    with Image.open(path) as im:
        assert im.n_frames == 3 and im.info["duration"] == 100
    with pytest.raises(MissingDependencyError, match="--video gif"):
        write_animation(_frames(), tmp_path / "t", fmt="mp4")
    with pytest.raises(ConfigError, match="fps"):
        write_animation(_frames(), tmp_path / "t", fps=0)
    with pytest.raises(ConfigError, match="empty"):
        write_animation([], tmp_path / "t")


def test_mp4_goes_through_ffmpeg_when_on_path(tmp_path, monkeypatch) -> None:
    # a stand-in `ffmpeg` that records its arguments and the raw frames it was piped
    fake = tmp_path / "bin" / "ffmpeg"
    fake.parent.mkdir()
    fake.write_text(
        "#!/bin/sh\n"
        f'echo "$@" > {tmp_path}/args.txt\n'
        f"cat > {tmp_path}/frames.raw\n"
        'for last; do true; done; echo mp4 > "$last"\n'
    )
    fake.chmod(fake.stat().st_mode | stat.S_IEXEC)
    monkeypatch.setenv("PATH", f"{fake.parent}{os.pathsep}{os.environ['PATH']}")
    assert mp4_encoder() == "ffmpeg"
    path = write_animation(_frames(), tmp_path / "t", fmt="auto", fps=12)
    assert path == tmp_path / "t.mp4" and path.read_text().strip() == "mp4"
    args = (tmp_path / "args.txt").read_text()
    assert "-s 8x10" in args and "libx264" in args and "yuv420p" in args  # padded to even sides
    assert (tmp_path / "frames.raw").stat().st_size == 3 * 10 * 8 * 3


def test_cli_turntable_writes_gif_when_no_mp4_encoder(tmp_path, model_dir, envmaps, monkeypatch):
    monkeypatch.setattr(_video, "mp4_encoder", lambda: None)
    Image.fromarray(_rgba(90)).save(tmp_path / "obj.png")
    args = ["relight", str(tmp_path / "obj.png"), "--envmap", str(envmaps / "b.exr")]
    args += ["--azimuth", "0", "--elevation", "0", "--checkpoint", str(model_dir), "--steps", "1"]
    args += ["--out", str(tmp_path / "spin.png"), "--turntable", "2", "--video", "auto"]
    assert main(args) == 0
    assert (tmp_path / "spin.gif").is_file() and (tmp_path / "spin_001.png").is_file()
    assert main([*args[:-1], "mp4"]) == 2
    assert torch.is_tensor(torch.zeros(1))
