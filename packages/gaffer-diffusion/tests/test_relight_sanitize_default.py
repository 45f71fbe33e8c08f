"""`relight --sanitize` defaults to gaffer-envmap's own policy, "raise": the tiny
negatives of lossy compression (7 of the 8 bundled HDRIs) become 0 with an INFO line, a NaN map is
refused in one line naming the flag (the default was "zero", which zeroed it silently)."""

import logging
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from gaffer_diffusion.cli import _parser, main
from gaffer_diffusion.cli._from_args import _envmap_lighting, _lights
from gaffer_envmap import bundled_hdris
from gaffer_envmap.io import write_envmap


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("sanitize") / "model"
    assert main(["init-random", "--preset", "tiny", "--out", str(d)]) == 0
    return d


def _photo(path: Path) -> Path:
    a = np.zeros((40, 30, 4), np.uint8)
    a[..., :3] = 90
    a[8:30, 5:25, 3] = 255
    Image.fromarray(a).save(path)
    return path


def _nan_map(path: Path) -> Path:
    x = np.ones((8, 16, 3), np.float32)
    x[1, 2, 0] = np.nan
    path.parent.mkdir(parents=True, exist_ok=True)
    write_envmap(path, x)
    return path


def test_every_bundled_hdri_relights_by_default(caplog: pytest.LogCaptureFixture) -> None:
    tiny = {}
    for name in sorted(bundled_hdris()):
        pose = ["--azimuth", "30", "--elevation", "10"]
        args = _parser().parse_args(
            ["relight", "in.png", "--envmap", name, *pose, "--out", "o.png"]
        )
        assert args.sanitize == "raise"
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="gaffer_envmap.sanitize"):
            _lights(args)  # the request's one read, with --sanitize
            maps = _envmap_lighting(args, args.envmap, 32)  # the read that conditions the model
        assert bool(maps.hdr.isfinite().all()) and bool((maps.hdr >= 0).all())
        tiny[name] = sum("tiny negative" in r.message for r in caplog.records)
    # 7 maps hold compression noise, each said at INFO (once per read); city is clean
    assert len(tiny) == 8 and sorted(n for n, k in tiny.items() if not k) == ["city"], tiny


def test_a_nan_map_is_refused_by_default_and_zeroed_on_request(
    tmp_path: Path, model_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    nan = _nan_map(tmp_path / "nan.exr")
    out = tmp_path / "o.png"
    argv = ["relight", str(_photo(tmp_path / "obj.png")), "--envmap", str(nan)]
    argv += ["--azimuth", "0", "--elevation", "0", "--checkpoint", str(model_dir)]
    argv += ["--steps", "1", "--out", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert "nan.exr" in err and "1 NaN" in err
    assert "--sanitize zero" in err and "--sanitize clamp" in err
    assert "`--sanitize raise` refused it" in err
    assert not out.exists()
    assert main([*argv, "--sanitize", "zero"]) == 0 and out.is_file()


def test_a_nan_map_in_envmaps_is_refused_before_the_weights_load(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import gaffer_diffusion.cli.relight as relight

    def no_model(*_: object) -> None:
        raise AssertionError("the model was loaded")

    monkeypatch.setattr(relight, "_load_model", no_model)
    maps = tmp_path / "maps"
    _nan_map(maps / "b.exr")
    write_envmap(maps / "a.exr", np.ones((8, 16, 3), np.float32))
    argv = ["relight", str(_photo(tmp_path / "obj.png")), "--envmaps", str(maps)]
    argv += ["--azimuth", "0", "--elevation", "0", "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "b.exr" in err and "--sanitize zero" in err
    assert not (tmp_path / "o").exists()
