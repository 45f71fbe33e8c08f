"""`gaffer-diffusion app` through its API (gradio_client): previews, relight at the photo's size or
the model's, the automatic mask, turntable GIF and MP4, refusals.

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


def _on_canvas(photo: Path, out: Path, size: tuple[int, int], at: tuple[int, int]) -> Path:
    """The RGBA example placed on a larger transparent canvas (a photo bigger than the model)."""
    canvas = Image.new("RGBA", size, (0, 0, 0, 0))
    canvas.alpha_composite(Image.open(photo).convert("RGBA"), at)
    canvas.save(out)
    return out


def _rgb_photo(photo: Path, out: Path) -> Path:
    """The example on an opaque grey-blue gradient, 240x180, saved without alpha (JPEG)."""
    grad = np.zeros((180, 240, 4), np.uint8)
    grad[..., 0] = np.linspace(70, 140, 240)[None, :].astype(np.uint8)
    grad[..., 1], grad[..., 2], grad[..., 3] = 110, 150, 255
    canvas = Image.fromarray(grad)
    canvas.alpha_composite(Image.open(photo).convert("RGBA"), (56, 26))
    canvas.convert("RGB").save(out, quality=95)
    return out


def _job(
    photo: Path | None, mask: Path | None = None, hdri: str = "sunset", size: str = "photo"
) -> list[Any]:
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
        size,  # output size: "photo" (full size, pasted back) or "model" (the crop)
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
        compat=pretrained.gaffer_tiny_sampling().compat,  # gaffer-tiny's, from its manifest
    )
    want = (maps.ldr[0].permute(1, 2, 0) * 255).round().to(torch.uint8).numpy()
    assert np.abs(ldr_a.astype(int) - want.astype(int)).max() <= 1
    # the sliders matter: another azimuth turns the map
    ldr2, _, _ = client.predict(TINY, "sunset", None, 120.0, 10.0, 0.0, api_name="/preview")
    assert np.abs(_rgb(ldr2).astype(int) - ldr_a.astype(int)).mean() > 2.0


def _cli(photo: Path, out: Path, *extra: str) -> np.ndarray:
    from gaffer_diffusion.cli import main
    from gaffer_envmap.bundled import bundled_hdri

    argv = ["relight", str(photo), "--envmap", str(bundled_hdri("sunset"))]
    argv += ["--azimuth", str(POSE[0]), "--elevation", str(POSE[1]), "--out", str(out)]
    assert main([*argv, *extra, "--device", "cpu"]) == 0
    with Image.open(out) as im:
        return np.asarray(im)


def test_relight_full_size_matches_the_cli(client: Any, tmp_path: Path) -> None:
    """The default output is the photo at its own size, relit object pasted back (alpha kept)."""
    photo = _on_canvas(_example()[0], tmp_path / "wide.png", (300, 200), (150, 40))
    _, mask, relit, download, status = client.predict(*_job(photo), api_name="/relight")
    with Image.open(relit) as im:
        relit_a = np.asarray(im)
    assert relit_a.shape == (200, 300, 4), relit_a.shape  # the photo's size; its alpha kept
    assert np.asarray(Image.open(mask).convert("L")).shape == (200, 300)
    assert "300x200" in status and "detail transfer" in status
    with Image.open(download["value"]) as im:
        assert np.asarray(im).tolist() == relit_a.tolist()
    want = _cli(photo, tmp_path / "cli.png")  # the CLI's default: the input's size
    diff = np.abs(relit_a.astype(int) - want.astype(int))
    assert diff.max() <= 1, f"app and CLI differ by up to {diff.max()} levels"
    src = np.asarray(Image.open(photo))
    outside = src[..., 3] == 0
    assert (relit_a[outside] == src[outside]).all()  # the rest of the photo: its own bytes
    inside = src[..., 3] > 200
    assert np.abs(relit_a[..., :3].astype(int) - src[..., :3].astype(int))[inside].mean() > 3.0


def test_relight_model_crop_matches_the_cli(client: Any, tmp_path: Path) -> None:
    photo, _ = _example()
    prepared, mask, relit, download, status = client.predict(
        *_job(photo, size="model"), api_name="/relight"
    )
    relit_a = _rgb(relit)
    assert relit_a.shape == (128, 128, 3)
    assert _rgb(download["value"]).tolist() == relit_a.tolist()
    assert "gaffer-tiny" in status and "128x128" in status and "crop" in status
    want = _cli(photo, tmp_path / "cli.png", "--output-size", "model")[..., :3]
    diff = np.abs(relit_a.astype(int) - want.astype(int))
    assert diff.max() <= 1, f"app and CLI differ by up to {diff.max()} levels"
    # it relit something: the object changed, the background outside the mask stayed white
    inp = _rgb(prepared)
    m = np.asarray(Image.open(mask).convert("L"))  # the crop's mask, beside the crop
    assert np.abs(relit_a.astype(int) - inp.astype(int))[m > 200].mean() > 3.0
    assert np.abs(relit_a.astype(int) - inp.astype(int))[m == 0].max() <= 1


def test_rgb_photo_gets_the_auto_mask(client: Any, tmp_path: Path) -> None:
    """An RGB photo without a mask: GrabCut's mask is shown, used, and can be replaced."""
    example, alpha = _example()
    rgb = _rgb_photo(example, tmp_path / "photo.jpg")
    from gradio_client import handle_file

    auto, note = client.predict(handle_file(str(rgb)), None, api_name="/auto_mask")
    auto_a = np.asarray(Image.open(auto).convert("L"))
    assert auto_a.shape == (180, 240) and "GrabCut" in note
    truth = np.zeros((180, 240), bool)
    truth[26:154, 56:184] = np.asarray(Image.open(alpha).convert("L")) > 127
    iou = ((auto_a > 127) & truth).sum() / ((auto_a > 127) | truth).sum()
    assert iou > 0.8, f"GrabCut's mask overlaps the object by IoU {iou:.2f}"
    _, used, relit, _, status = client.predict(*_job(rgb), api_name="/relight")
    assert _rgb(relit).shape == (180, 240, 3)  # the photo's size
    assert np.asarray(Image.open(used).convert("L")).tolist() == auto_a.tolist()
    assert "GrabCut" in status and "upload a corrected mask" in status
    src = _rgb(rgb)
    outside = auto_a == 0
    assert (_rgb(relit)[outside] == src[outside]).all()
    # the user's own mask replaces it
    own = tmp_path / "own.png"
    Image.fromarray(truth.astype(np.uint8) * 255).save(own)
    _, used, _, _, status = client.predict(*_job(rgb, own), api_name="/relight")
    assert np.asarray(Image.open(used).convert("L")).tolist() == (truth * 255).tolist()
    assert "GrabCut" not in status


def test_mask_of_another_size_is_refused(client: Any, tmp_path: Path) -> None:
    from gradio_client.exceptions import AppError

    rgb = _rgb_photo(_example()[0], tmp_path / "photo.jpg")
    small = tmp_path / "small.png"
    Image.new("L", (64, 48), 255).save(small)
    with pytest.raises(AppError, match=r"64x48 but the image .* is 240x180"):
        client.predict(*_job(rgb, small), api_name="/relight")


def _mp4_backend() -> str | None:
    from gaffer_diffusion.app.engine import mp4_backend

    return mp4_backend()


def test_turntable_gif_and_mp4(client: Any) -> None:
    photo, _ = _example()
    gif, download, mp4, status = client.predict(*_job(photo), 4, 8, api_name="/turntable")
    assert Path(gif).suffix == ".gif" and Path(download["value"]).suffix == ".gif"
    assert "4 frames" in status
    with Image.open(gif) as im:
        assert im.n_frames == 4 and im.size == (128, 128)  # the photo's size
        frames = []
        for k in range(im.n_frames):
            im.seek(k)
            frames.append(np.asarray(im.convert("RGB")).astype(int))
    # the light turns: every frame differs from the first
    assert all(np.abs(f - frames[0]).mean() > 1.0 for f in frames[1:])
    if _mp4_backend() is None:
        pytest.skip("no MP4 encoder here (ffmpeg, PyAV or OpenCV); test_app_mp4 covers the page")
    video = Path(mp4["value"])
    assert video.suffix == ".mp4"
    with video.open("rb") as f:
        head = f.read(12)
    assert head[4:8] == b"ftyp", head  # an ISO base media file, as MP4 players expect
    cv2 = pytest.importorskip("cv2")
    cap = cv2.VideoCapture(str(video))
    try:
        n, size = 0, None
        while True:
            ok, frame = cap.read()
            if not ok:
                break
            n, size = n + 1, frame.shape[:2]
    finally:
        cap.release()
    assert n == 4 and size == (128, 128)


def test_turntable_frames_are_capped(client: Any, tmp_path: Path) -> None:
    """A photo larger than `--max-turntable-side` (512) gives frames shrunk to it, aspect kept."""
    photo = _on_canvas(_example()[0], tmp_path / "big.png", (1000, 500), (436, 186))
    gif, _, _, status = client.predict(*_job(photo), 2, 8, api_name="/turntable")
    with Image.open(gif) as im:
        assert im.size == (512, 256)
    assert "1000x500 photo shrunk" in status


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
