"""`gaffer-diffusion app` options and start-up: refused before Gradio loads, safe defaults, clean exit."""

import os
import tempfile
from pathlib import Path
from typing import Any

import pytest

from gaffer_diffusion.app.config import AppConfig, config_from_args
from gaffer_diffusion.app.engine import CameraPose
from gaffer_diffusion.cli import _parser, main
from gaffer_diffusion.errors import ConfigError, InputValueError, MissingDependencyError


def _args(*argv: str) -> Any:
    return _parser().parse_args(["app", *argv])


def test_defaults_are_local_only() -> None:
    config = config_from_args(_args())
    assert config.host == "127.0.0.1" and config.port == 7860
    assert [m.label for m in config.models] == ["gaffer-tiny (shipped)"]
    assert config.max_upload_bytes == 20 * 1024 * 1024
    assert config.dtype == "auto"  # as `gaffer-diffusion relight --dtype`
    assert config_from_args(_args("--dtype", "float32")).dtype == "float32"
    with pytest.raises(SystemExit):  # argparse names the choices
        _args("--dtype", "float64")


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["--port", "0"], "`--port` is 0"),
        (["--threads", "0"], "`--threads`"),
        (["--max-upload-mb", "-1"], "`--max-upload-mb`"),
        (["--max-image-side", "10"], "`--max-image-side`"),
        (["--queue-size", "0"], "`--queue-size`"),
        (["--max-frames", "1"], "`--max-frames`"),
    ],
)
def test_bad_values_name_the_flag(argv: list[str], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        config_from_args(_args(*argv))


def test_model_folders_are_checked_up_front(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="is not a folder"):
        config_from_args(_args("--model", str(tmp_path / "missing")))
    with pytest.raises(ConfigError, match="needs `--base-model DIR`"):
        config_from_args(_args("--model", str(tmp_path)))
    base = tmp_path / "zero123-xl"
    base.mkdir()
    config = config_from_args(_args("--model", str(tmp_path), "--base-model", str(base)))
    assert config.models[1].base_model == base


def test_cli_refuses_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["app", "--port", "70000"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: `--port` is 70000") and err.count("\n") == 1


def test_pose_checks_its_values() -> None:
    with pytest.raises(InputValueError, match="`elevation_deg` is 91"):
        CameraPose(elevation_deg=91.0)
    with pytest.raises(InputValueError, match="`spin_deg`"):
        CameraPose(spin_deg=float("nan"))


def test_serve_sets_gradio_env_and_cleans_up(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Analytics off and the cache in the app's folder before Gradio loads; the folder goes on exit."""
    from gaffer_diffusion.app import server

    seen: dict[str, str] = {}

    def no_gradio() -> None:
        seen.update({k: os.environ[k] for k in ("GRADIO_ANALYTICS_ENABLED", "GRADIO_TEMP_DIR")})
        raise MissingDependencyError('pip install "gaffer-diffusion[app]"')

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.setattr(server, "_import_gradio", no_gradio)
    monkeypatch.delenv("GRADIO_ANALYTICS_ENABLED", raising=False)
    monkeypatch.delenv("GRADIO_TEMP_DIR", raising=False)
    with pytest.raises(MissingDependencyError, match=r"gaffer-diffusion\[app\]"):
        server.serve(AppConfig())
    assert seen["GRADIO_ANALYTICS_ENABLED"] == "False"
    assert Path(seen["GRADIO_TEMP_DIR"]).parent.parent == tmp_path
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_stopping_the_server_removes_its_files(start_app_fn: Any, tmp_path: Path) -> None:
    """SIGTERM after a relight: exit status 0 and nothing left in the server's TMPDIR."""
    pytest.importorskip("gradio_client")
    from gradio_client import Client, handle_file

    from gaffer_diffusion.pretrained import example_dataset_path

    start, stop = start_app_fn
    app = start(tmp_path)
    photo = sorted((example_dataset_path() / "objects").iterdir())[0] / "lit" / "000_000.png"
    try:
        client = Client(app.url, verbose=False, download_files=str(tmp_path / "downloads"))
        args = [
            "gaffer-tiny (shipped)",
            handle_file(str(photo)),
            None,
            "city",
            None,
            0,
            0,
            0,
            None,
            0,
        ]
        client.predict(*args, api_name="/relight")
        assert any(app.tmpdir.iterdir()), "the server wrote nothing under its TMPDIR"
    finally:
        status = stop(app)
    assert status == 0, app.log_text()[-2000:]
    assert list(app.tmpdir.iterdir()) == []
