"""`gaffer-diffusion app` through its API (gradio_client): previews, relight, turntable, refusals.

The server is a separate process (conftest.py); the images it returns are checked against the
library called directly, so the page shows what `gaffer-diffusion relight` computes.
"""

import json
import re
import urllib.request
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

pytestmark = pytest.mark.slow

TINY = "gaffer-tiny (shipped)"
POSE = (30.0, 10.0, 0.0)  # azimuth, elevation, spin


def _example() -> tuple[Path, Path]:
    """The shipped example's input view (RGBA) and its separate alpha mask."""
    from gaffer_diffusion.pretrained import example_dataset_path

    obj = sorted((example_dataset_path() / "objects").iterdir())[0]
    return obj / "lit" / "000_000.png", obj / "alpha" / "000.png"


@pytest.fixture(scope="module")
def client(app_server: Any, tmp_path_factory: pytest.TempPathFactory) -> Any:
    from gradio_client import Client

    return Client(
        app_server.url, verbose=False, download_files=str(tmp_path_factory.mktemp("downloads"))
    )


def _rgb(path: str | Path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def _job(photo: Path | None, mask: Path | None = None, hdri: str = "sunset") -> list[Any]:
    from gradio_client import handle_file

    return [
        TINY,
        None if photo is None else handle_file(str(photo)),
        None if mask is None else handle_file(str(mask)),
        hdri,
        None,
        *POSE,
        None,  # steps: the model's suggestion
        0,  # seed
    ]


def test_preview_shows_the_library_encoding(client: Any) -> None:
    import torch

    from gaffer_diffusion import pretrained
    from gaffer_diffusion.conditioning import lighting_from_envmap
    from gaffer_envmap.bundled import read_bundled_hdri
    from gaffer_envmap.poses import orbit_w2c_blender

    ldr, hdr, view = client.predict(TINY, "sunset", None, *POSE, api_name="/preview")
    ldr_a, hdr_a, view_a = _rgb(ldr), _rgb(hdr), _rgb(view)
    assert ldr_a.shape == hdr_a.shape == (128, 128, 3)
    assert view_a.shape == (128, 256, 3)
    maps = lighting_from_envmap(
        read_bundled_hdri("sunset"),
        [orbit_w2c_blender(POSE[0], POSE[1])],
        size=128,
        compat=pretrained.GAFFER_TINY_COMPAT,  # type: ignore[arg-type]
    )
    want = (maps.ldr[0].permute(1, 2, 0) * 255).round().to(torch.uint8).numpy()
    assert np.abs(ldr_a.astype(int) - want.astype(int)).max() <= 1
    # the sliders matter: another azimuth turns the map
    ldr2, _, _ = client.predict(TINY, "sunset", None, 120.0, 10.0, 0.0, api_name="/preview")
    assert np.abs(_rgb(ldr2).astype(int) - ldr_a.astype(int)).mean() > 2.0


def test_relight_matches_the_cli(client: Any, tmp_path: Path) -> None:
    from gaffer_diffusion.cli import main
    from gaffer_envmap.bundled import bundled_hdri

    photo, _ = _example()
    prepared, mask, relit, download, status = client.predict(*_job(photo), api_name="/relight")
    relit_a = _rgb(relit)
    assert relit_a.shape == (128, 128, 3)
    assert _rgb(download["value"]).tolist() == relit_a.tolist()
    assert "gaffer-tiny" in status and "128x128" in status
    reference = tmp_path / "cli.png"
    argv = ["relight", str(photo), "--envmap", str(bundled_hdri("sunset"))]
    argv += ["--azimuth", str(POSE[0]), "--elevation", str(POSE[1]), "--out", str(reference)]
    argv += ["--output-size", "model"]  # the app shows the model's crop
    assert main([*argv, "--device", "cpu"]) == 0
    diff = np.abs(relit_a.astype(int) - _rgb(reference).astype(int))
    assert diff.max() <= 1, f"app and CLI differ by up to {diff.max()} levels"
    # it relit something: the object changed, the background outside the mask stayed white
    inp, m = _rgb(prepared), np.asarray(Image.open(mask).convert("L"))
    assert np.abs(relit_a.astype(int) - inp.astype(int))[m > 200].mean() > 3.0
    assert np.abs(relit_a.astype(int) - inp.astype(int))[m == 0].max() <= 1


def test_rgb_photo_needs_a_mask(client: Any, tmp_path: Path) -> None:
    from gradio_client.exceptions import AppError

    photo, alpha = _example()
    rgb = tmp_path / "photo.jpg"
    Image.open(photo).convert("RGB").save(rgb, quality=95)
    with pytest.raises(AppError, match=r"no alpha channel.*upload a mask"):
        client.predict(*_job(rgb), api_name="/relight")
    _, mask, relit, _, _ = client.predict(*_job(rgb, alpha), api_name="/relight")
    assert _rgb(relit).shape == (128, 128, 3)
    assert np.asarray(Image.open(mask).convert("L")).max() == 255


def test_turntable_gif(client: Any) -> None:
    photo, _ = _example()
    gif, download, status = client.predict(*_job(photo), 4, 8, api_name="/turntable")
    assert Path(gif).suffix == ".gif" and Path(download["value"]).suffix == ".gif"
    assert "4 frames" in status
    with Image.open(gif) as im:
        assert im.n_frames == 4 and im.size == (128, 128)
        frames = []
        for k in range(im.n_frames):
            im.seek(k)
            frames.append(np.asarray(im.convert("RGB")).astype(int))
    # the light turns: every frame differs from the first
    assert all(np.abs(f - frames[0]).mean() > 1.0 for f in frames[1:])


def test_turntable_frame_limit(client: Any) -> None:
    from gradio_client.exceptions import AppError

    photo, _ = _example()
    with pytest.raises(AppError, match="greater than maximum value 8"):
        client.predict(*_job(photo), 9, 8, api_name="/turntable")


def test_bad_envmap_is_explained_without_server_paths(client: Any, tmp_path: Path) -> None:
    from gradio_client import handle_file
    from gradio_client.exceptions import AppError

    bad = tmp_path / "studio.exr"
    bad.write_bytes(b"this is not an EXR file")
    with pytest.raises(AppError) as info:
        client.predict(TINY, "sunset", handle_file(str(bad)), *POSE, api_name="/preview")
    message = str(info.value)
    assert "not a valid OpenEXR file" in message and "studio.exr" in message
    assert not re.search(r"[0-9a-f]{64}", message), message
    txt = tmp_path / "notes.txt"
    txt.write_text("hello")
    with pytest.raises(AppError, match=r"(?i)invalid file type.*\.exr"):
        client.predict(TINY, "sunset", handle_file(str(txt)), *POSE, api_name="/preview")


def test_image_size_limit(client: Any, app_server: Any, tmp_path: Path) -> None:
    from gradio_client.exceptions import AppError

    big = tmp_path / "wide.png"
    Image.new("RGBA", (app_server.max_image_side + 1, 8), (255, 0, 0, 255)).save(big)
    with pytest.raises(AppError, match="--max-image-side"):
        client.predict(*_job(big), api_name="/relight")


def test_upload_size_limit(client: Any, app_server: Any, tmp_path: Path) -> None:
    noise = np.random.default_rng(0).integers(0, 256, (700, 700, 4), dtype=np.uint8)
    big = tmp_path / "noise.png"
    Image.fromarray(noise).save(big)
    assert big.stat().st_size > app_server.max_upload_mb * 1024 * 1024
    with pytest.raises(Exception, match=r"(?i)too large|413|max.*size"):
        client.predict(*_job(big), api_name="/relight")


def test_page_config_is_private(app_server: Any) -> None:
    with urllib.request.urlopen(app_server.url + "config", timeout=10) as response:
        config = json.load(response)
    assert config["analytics_enabled"] is False
    assert config["max_file_size"] == int(app_server.max_upload_mb * 1024 * 1024)
    named = {d.get("api_name") for d in config["dependencies"]}
    assert {"preview", "relight", "turntable"} <= named


def test_jobs_run_one_at_a_time(client: Any) -> None:
    """A relight sent while a turntable samples waits for it (one model, one job, one queue)."""
    import time

    from gradio_client.utils import Status

    photo, _ = _example()
    spin = client.submit(*_job(photo), 8, 8, api_name="/turntable")
    deadline = time.monotonic() + 60
    while spin.status().code != Status.PROCESSING and not spin.done():
        if time.monotonic() > deadline:
            pytest.fail(f"the turntable never started: {spin.status()}")
        time.sleep(0.02)  # polling the job's status: gradio_client has no blocking wait for it
    single = client.submit(*_job(photo), api_name="/relight")
    single.result(timeout=120)
    # had they run side by side, the 1-frame relight would finish long before the 8-frame turntable
    assert spin.done(), "a relight ran beside a running turntable"
    assert Path(spin.result(timeout=60)[0]).suffix == ".gif"
