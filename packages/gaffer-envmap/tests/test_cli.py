"""The `gaffer-envmap` CLI: each command end to end, bad input -> exit 2 and nothing written."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from gaffer_envmap import orbit_w2c_blender, read_envmap, write_envmap
from gaffer_envmap.cli import main
from gaffer_envmap.testing import disc_sun_map


@pytest.fixture
def scene(tmp_path: Path) -> tuple[Path, Path]:
    env = disc_sun_map(32, np.array([0.0, 1.0, 0.5]), 5.0, 500.0, sky=0.3)
    src = tmp_path / "sky.exr"
    write_envmap(src, env)
    w2c = tmp_path / "000_RT.npy"
    np.save(w2c, orbit_w2c_blender(30, 20, 2.0).matrix)
    return src, w2c


def test_info_json(scene: tuple[Path, Path], capsys: pytest.CaptureFixture[str]) -> None:
    src, _ = scene
    assert main(["info", str(src), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["height"] == 32 and info["nan_count"] == 0
    assert info["dominant_direction"][1] > 0.8


def test_info_reports_the_stored_minimum_of_a_map_with_negatives(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # `info` said min_value 0.0 for a map with 826 negative pixels
    from gaffer_envmap import write_envmap

    x = np.ones((8, 16, 3), np.float32)
    x[1, 2, 0] = -0.003
    x[3, 4, 1] = -0.5
    write_envmap(tmp_path / "neg.exr", x, dtype="float32")
    assert main(["info", str(tmp_path / "neg.exr"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["negative_count"] == 2
    assert info["min_value"] == pytest.approx(-0.5)


def test_rotate_writes_float32_exr(scene: tuple[Path, Path], tmp_path: Path) -> None:
    src, w2c = scene
    dst = tmp_path / "cam.exr"
    assert (
        main(["rotate", str(src), str(dst), "--w2c", str(w2c), "--size", "16", "--spin", "45"]) == 0
    )
    out = read_envmap(dst)
    assert out.radiance_linear.shape == (16, 32, 3)


@pytest.mark.parametrize("compat", ["default", "neural-gaffer"])
def test_encode_writes_two_256_pngs(scene: tuple[Path, Path], tmp_path: Path, compat: str) -> None:
    src, w2c = scene
    out = tmp_path / "enc"
    assert (
        main(["encode", str(src), "--w2c", str(w2c), "--out-dir", str(out), "--compat", compat])
        == 0
    )
    for name in ("ldr.png", "hdr.png"):
        with Image.open(out / name) as img:
            assert img.size == (256, 256) and img.mode == "RGB"


def test_augment_writes_sixteen_maps(scene: tuple[Path, Path], tmp_path: Path) -> None:
    src, _ = scene
    out = tmp_path / "aug"
    assert main(["augment", str(src), "--out-dir", str(out), "--flips", "--yaw-steps", "8"]) == 0
    assert len(list(out.glob("*.exr"))) == 16


def test_bad_input_exits_2_and_writes_nothing(
    scene: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    src, w2c = scene
    bad_pose = tmp_path / "bad.npy"
    np.save(bad_pose, np.eye(3, 4) * 2)
    dst = tmp_path / "never.exr"
    assert main(["rotate", str(src), str(dst), "--w2c", str(bad_pose)]) == 2
    assert "not a rotation" in capsys.readouterr().err and not dst.exists()
    broken = tmp_path / "broken.exr"
    broken.write_bytes(src.read_bytes()[:200])
    out = tmp_path / "enc"
    assert main(["encode", str(broken), "--w2c", str(w2c), "--out-dir", str(out)]) == 2
    assert not (out / "ldr.png").exists()
    assert main(["info", str(tmp_path / "missing.exr")]) == 2


def test_console_script_module_runs() -> None:
    res = subprocess.run(
        [sys.executable, "-m", "gaffer_envmap.cli", "--help"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert res.returncode == 0 and "encode" in res.stdout


def test_demo_runs_on_the_bundled_hdri(tmp_path: Path) -> None:
    assert main(["demo", "--out", str(tmp_path), "--size", "64"]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    with Image.open(tmp_path / "overview.png") as sheet:
        assert summary["views"] == 4 and sheet.size[0] > 500
    assert (tmp_path / "view_0" / "compat_hdr.png").exists()


def test_encode_compat_spin_is_the_authors_frame(scene: tuple[Path, Path], tmp_path: Path) -> None:
    """`encode --compat neural-gaffer --spin D` writes their turntable frame k = D / 360 * N."""
    from gaffer_envmap.testing import reference_neural_gaffer

    src, w2c = scene
    out = tmp_path / "enc"
    args = ["encode", str(src), "--w2c", str(w2c), "--out-dir", str(out), "--size", "32"]
    assert main([*args, "--compat", "neural-gaffer", "--spin", "135"]) == 0
    env, pose = read_envmap(src).radiance_linear, np.load(w2c)
    ref_ldr, ref_hdr = reference_neural_gaffer(env, pose, 32, frame=3, num_frames=8)
    for name, ref in (("ldr.png", ref_ldr), ("hdr.png", ref_hdr)):
        with Image.open(out / name) as img:
            assert np.array_equal(np.asarray(img), ref), name
