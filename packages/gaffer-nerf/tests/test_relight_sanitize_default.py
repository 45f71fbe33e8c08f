"""`gaffer-nerf relight --sanitize` defaults to gaffer-envmap's own policy, "raise": the 8
bundled HDRIs (7 with the tiny negatives of lossy compression) work, a NaN map is refused
in one line naming the flag (the default was "zero", which zeroed it silently)."""

import logging
from pathlib import Path

import numpy as np
import pytest

from gaffer_envmap import bundled_hdris
from gaffer_envmap.io import write_envmap
from gaffer_nerf.cli import _parser, _target_envmap, main
from gaffer_nerf.errors import ConfigError
from gaffer_nerf.testing import write_sphere_scene


def _args(envmap: str, *extra: str):
    return _parser().parse_args(
        ["relight", "field", "--data", "scene", "--envmap", envmap, "--out", "r", *extra]
    )


def test_every_bundled_hdri_is_read_by_default(caplog: pytest.LogCaptureFixture) -> None:
    tiny = {}
    for name in sorted(bundled_hdris()):
        args = _args(name)
        assert args.sanitize == "raise"
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="gaffer_envmap.sanitize"):
            env = _target_envmap(args, None)  # what relight conditions on
        rgb = env.radiance_linear
        assert np.isfinite(rgb).all() and (rgb >= 0).all()
        tiny[name] = any("tiny negative" in r.message for r in caplog.records)
    assert len(tiny) == 8 and sorted(n for n, t in tiny.items() if not t) == ["city"], tiny


def test_a_nan_map_is_refused_by_default_and_zeroed_on_request(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    x = np.ones((8, 16, 3), np.float32)
    x[1, 2, 0] = np.nan
    nan = tmp_path / "nan.exr"
    write_envmap(nan, x)
    with pytest.raises(ConfigError, match=r"1 NaN.*--sanitize zero.*`--sanitize raise` refused it"):
        _target_envmap(_args(str(nan)), None)
    assert _target_envmap(_args(str(nan), "--sanitize", "zero"), None).radiance_linear[1, 2, 0] == 0
    # the command line: one line, exit 2, nothing written (a real field, as preflight checks it)
    scene = write_sphere_scene(tmp_path / "scene", train_views=3, test_views=1, resolution=32)
    field = tmp_path / "field"
    fit = ["fit", str(scene.root), "--out", str(field), "--preset", "tiny", "--iterations", "2"]
    assert main([*fit, "--device", "cpu", "--no-progress"]) == 0
    capsys.readouterr()
    out = tmp_path / "r"
    argv = ["relight", str(field), "--data", str(scene.root), "--envmap", str(nan)]
    argv += ["--out", str(out), "--no-progress", "--device", "cpu"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert "nan.exr" in err and "--sanitize zero" in err and not out.exists()
