"""`gaffer-nerf fit | relight | render | evaluate` on a written tiny scene (in-process)."""

import json
from pathlib import Path

import pytest

from gaffer_nerf.cli import main
from gaffer_nerf.testing import write_sphere_scene


def test_cli_round_trip(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    s = write_sphere_scene(tmp_path / "scene", train_views=6, test_views=2, resolution=64)
    data, field, relit = str(s.root), tmp_path / "field", tmp_path / "relit"
    common = ["--device", "cpu", "--no-progress"]
    fit = ["fit", data, "--out", str(field), "--preset", "tiny", "--iterations", "60"]
    assert main([*fit, "--rank-ladder", "1.0", *common]) == 0  # a one-rung ladder: one fit
    assert (field / "field.safetensors").is_file() and (field / "fit_report.json").is_file()
    ladder = json.loads((field / "fit_report.json").read_text())["rank_selection"]
    assert ladder["chosen"] == 0 and ladder["rungs"][0]["appearance_ranks"] == [8, 8, 8]
    assert "held out" in capsys.readouterr().out
    assert main([
        "relight", str(field), "--data", data, "--target-lighting", "1", "--envmaps", str(s.envmap_dir),
        "--diffusion-preset", "tiny", "--out", str(relit), "--preset", "tiny",
        "--stage1-iterations", "5", "--stage2-iterations", "2", "--steps", "4", *common,
    ]) == 0  # fmt: skip
    report = json.loads((relit / "relight_report.json").read_text())
    assert (
        report["report"]["stage1"]["iterations"] == 5
        and len(list((relit / "relit_views").glob("*.png"))) == 6
    )
    assert (
        main(["render", str(relit), "--data", data, "--out", str(tmp_path / "renders"), *common])
        == 0
    )
    assert len(list((tmp_path / "renders").glob("*.png"))) == 2
    orbit = tmp_path / "orbit"
    render = ["render", str(relit), "--data", data, "--out", str(orbit)]
    assert main([*render, "--orbit", "3", *common]) == 0
    assert len(list(orbit.glob("frame_*.png"))) == 3 and (orbit / "orbit.gif").is_file()
    out_json = tmp_path / "m.json"
    assert (
        main(
            [
                "evaluate",
                str(relit),
                "--data",
                data,
                "--target-lighting",
                "1",
                "--json",
                str(out_json),
                "--flicker",
                *common,
            ]
        )
        == 0
    )
    metrics = json.loads(out_json.read_text())
    assert metrics["perceptual_name"] == "stlpips-alex" and len(metrics["items"]) == 2
    assert metrics["flicker"]["frames"] == 2 and metrics["flicker"]["flicker"] >= 0
    out = capsys.readouterr().out
    assert "flicker along the 2 test views" in out
    assert "object mask, raw" in out and "aligned (mask means)" in out


def test_cli_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["fit", str(tmp_path), "--out", str(tmp_path / "f"), "--no-progress"]) == 2
    assert "transforms_train.json" in capsys.readouterr().err
    assert main(["evaluate", str(tmp_path / "f"), "--data", str(tmp_path), "--no-progress"]) == 2
    assert "--target-lighting" in capsys.readouterr().err
    s = write_sphere_scene(tmp_path / "s", train_views=2, test_views=1, resolution=8, lightings=1)
    (s.root / "transforms_test.json").unlink()
    fit = ["fit", str(s.root), "--out", str(tmp_path / "f"), "--rank-selection", "--no-progress"]
    assert main(fit) == 2
    assert "transforms_test.json" in capsys.readouterr().err
