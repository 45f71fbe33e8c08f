"""Relighting a photo at its own size: reading the photos people have, the model's framing,
paste-back with detail transfer, automatic masks, and the relight / prepare CLI around them."""

import io
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from gaffer_diffusion import cli, detail_transfer
from gaffer_diffusion.cli import main
from gaffer_diffusion.errors import InputValueError, MissingDependencyError
from gaffer_diffusion.photo import (
    envmap_backdrop,
    object_alpha,
    paste_back,
    prepare_photo,
    read_mask,
    read_photo,
)


def _scene(
    h: int = 120, w: int = 160, radius: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """A textured disc (checker print) on a smooth gradient: uint8 RGB and its boolean mask."""
    yy, xx = np.mgrid[:h, :w]
    r = min(h, w) * 0.3 if radius is None else radius
    disc = (yy - h / 2) ** 2 + (xx - w / 2) ** 2 < r**2
    bg = np.stack([0.3 + 0.3 * xx / w, 0.45 + 0 * yy, 0.6 - 0.3 * yy / h], -1)
    tex = 0.35 + 0.5 * ((xx // 4 + yy // 4) % 2)
    img = bg.copy()
    img[disc] = np.stack([tex, 0.6 * tex, 0.3 * tex], -1)[disc]
    return np.round(img * 255).astype(np.uint8), disc


def _save(arr: np.ndarray, path: Path, **kw) -> Path:
    Image.fromarray(arr).save(path, **kw)
    return path


def _relit(prepared, gain=(0.6, 0.9, 1.3)) -> torch.Tensor:
    """A stand-in model result: the model's input with its colour scaled (a pure change of light)."""
    return (prepared.model_input.image[0] * torch.tensor(gain)[:, None, None]).clamp(0, 1)


def test_paste_back_keeps_the_size_and_the_bytes_outside_the_mask(tmp_path) -> None:
    rgb, disc = _scene()
    photo = read_photo(_save(rgb, tmp_path / "p.png"))
    prepared = prepare_photo(photo, disc.astype(np.float32), size=32)
    for detail in ("transfer", "resize"):
        out = paste_back(prepared, _relit(prepared), detail=detail)
        assert out.shape == rgb.shape and out.dtype == np.uint8
        assert np.array_equal(out[~disc], rgb[~disc]), detail
        assert np.abs(out[disc].astype(int) - rgb[disc].astype(int)).mean() > 5, detail


def test_detail_transfer_keeps_texture_that_upsampling_loses(tmp_path) -> None:
    """The stand-in result is the input times a constant per channel, so the truth is known at full
    size: detail transfer must get it far closer than bicubic upsampling of the 32 px result."""
    rgb, disc = _scene(240, 320)
    photo = read_photo(_save(rgb, tmp_path / "p.png"))
    prepared = prepare_photo(photo, disc.astype(np.float32), size=32)
    gain = np.array([0.6, 0.9, 1.3], np.float32)
    truth_lin = detail_transfer.srgb_to_linear(rgb / 255.0) * gain**2.2  # sRGB gain ~ linear^2.2
    truth = np.round(detail_transfer.linear_to_srgb(truth_lin) * 255)
    inner = disc & (np.abs(np.gradient(disc.astype(float))[0]) == 0)

    def err(detail: str) -> float:
        out = paste_back(prepared, _relit(prepared, tuple(gain)), detail=detail)
        return float(np.abs(out[inner].astype(float) - truth[inner]).mean())

    assert err("transfer") < 0.5 * err("resize")


def test_guided_filter_matches_a_plain_reference() -> None:
    rng = np.random.default_rng(0)
    guide = rng.random((12, 10)).astype(np.float32)
    src = rng.random((12, 10)).astype(np.float32)
    r, eps = 2, 1e-2

    def mean(x: np.ndarray) -> np.ndarray:  # plain windowed mean, windows cut at the border
        out = np.empty_like(x)
        for i in range(x.shape[0]):
            for j in range(x.shape[1]):
                out[i, j] = x[max(i - r, 0) : i + r + 1, max(j - r, 0) : j + r + 1].mean()
        return out

    a = (mean(guide * src) - mean(guide) * mean(src)) / (
        mean(guide * guide) - mean(guide) ** 2 + eps
    )
    b = mean(src) - a * mean(guide)
    ref = mean(a) * guide + mean(b)
    np.testing.assert_allclose(detail_transfer.guided_filter(guide, src, r, eps), ref, atol=1e-5)


def test_push_pull_fills_holes_and_keeps_known_pixels() -> None:
    v = torch.arange(16.0).reshape(1, 4, 4)
    w = torch.ones(4, 4)
    w[1:3, 1:3] = 0
    out = detail_transfer.push_pull_fill(v, w)
    assert torch.equal(out[0][w > 0], v[0][w > 0])
    assert torch.isfinite(out).all() and out[0, 1:3, 1:3].min() > 0


# ----- inputs people have -----


def test_exif_orientation_is_applied(tmp_path) -> None:
    rgb, _ = _scene(40, 60)
    exif = Image.Exif()
    exif[0x0112] = 6  # rotate 90 CW on display
    Image.fromarray(rgb).save(tmp_path / "e.jpg", exif=exif, quality=95)
    photo = read_photo(tmp_path / "e.jpg")
    assert photo.size_wh == (40, 60)  # displayed upright: width and height swapped


def test_16_bit_grey_png_keeps_its_precision(tmp_path) -> None:
    grey = (np.linspace(0, 65535, 50 * 40).reshape(40, 50)).astype(np.uint16)
    Image.fromarray(grey).save(tmp_path / "g16.png")
    photo = read_photo(tmp_path / "g16.png")
    assert photo.rgb.shape == (40, 50, 3)
    np.testing.assert_allclose(photo.rgb[..., 0], grey / 65535.0, atol=1e-6)
    assert photo.rgb_u8[-1, -1, 0] == 255


@pytest.mark.parametrize("mode", ["L", "P", "CMYK", "RGB", "LA"])
def test_grey_palette_cmyk_and_jpeg_photos_read_as_rgb(tmp_path, mode) -> None:
    rgb, disc = _scene(40, 60)
    im = Image.fromarray(rgb).convert(mode)
    path = tmp_path / ("p.jpg" if mode in ("RGB", "CMYK") else "p.png")
    im.save(path)
    photo = read_photo(path)
    assert photo.rgb_u8.shape == (40, 60, 3) and photo.rgb_u8.dtype == np.uint8
    assert (photo.alpha is not None) == (mode == "LA")
    prepared = prepare_photo(photo, disc.astype(np.float32), size=16)
    out = paste_back(prepared, _relit(prepared))
    assert out.shape[:2] == (40, 60)


def test_photo_over_4k_is_relit_at_full_size(tmp_path) -> None:
    rgb, disc = _scene(2200, 4400, radius=500)
    photo = read_photo(_save(rgb, tmp_path / "big.png"))
    prepared = prepare_photo(photo, disc.astype(np.float32), size=32)
    assert prepared.model_input.image.shape == (1, 3, 32, 32)
    out = paste_back(prepared, _relit(prepared))
    assert out.shape == rgb.shape and np.array_equal(out[~disc], rgb[~disc])


def test_tiny_object_in_a_large_photo(tmp_path) -> None:
    rgb, disc = _scene(900, 1200, radius=6)
    photo = read_photo(_save(rgb, tmp_path / "p.png"))
    prepared = prepare_photo(photo, disc.astype(np.float32), size=64)
    assert prepared.framing.side_x < 20  # the model sees the object, not the photo
    out = paste_back(prepared, _relit(prepared))
    assert np.array_equal(out[~disc], rgb[~disc]) and not np.array_equal(out[disc], rgb[disc])


def test_mask_of_another_size_names_both_sizes(tmp_path) -> None:
    rgb, _ = _scene(40, 60)
    photo = read_photo(_save(rgb, tmp_path / "p.png"))
    _save(np.zeros((30, 20), np.uint8), tmp_path / "m.png")
    with pytest.raises(InputValueError, match=r"20x30.*60x40"):
        read_mask(tmp_path / "m.png", photo)


@pytest.mark.parametrize(("value", "word"), [(0, "all black"), (255, "all white")])
def test_all_black_or_white_mask_is_refused(tmp_path, value, word) -> None:
    rgb, _ = _scene(40, 60)
    photo = read_photo(_save(rgb, tmp_path / "p.png"))
    _save(np.full((40, 60), value, np.uint8), tmp_path / "m.png")
    with pytest.raises(InputValueError, match=word) as info:
        read_mask(tmp_path / "m.png", photo)
    assert "\n" not in str(info.value)


def test_rgb_photo_without_mask_names_mask_auto(tmp_path) -> None:
    rgb, _ = _scene(40, 60)
    photo = read_photo(_save(rgb, tmp_path / "p.png"))
    with pytest.raises(InputValueError, match="--mask auto"):
        object_alpha(photo, None)


def test_grabcut_finds_a_centred_object() -> None:
    pytest.importorskip("cv2")
    from gaffer_diffusion.automask import grabcut_mask

    rgb, disc = _scene(150, 200)
    m = grabcut_mask(rgb) > 0.5
    assert (m & disc).sum() / (m | disc).sum() > 0.9


def test_sam_checkpoint_without_segment_anything_is_one_line(tmp_path, monkeypatch) -> None:
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda n, *a: None if n == "segment_anything" else real(n, *a)
    )
    args = cli._parser().parse_args(
        ["relight", "x.png", "--out", "o.png", "--sam-checkpoint", str(tmp_path / "sam.pth")]
    )
    with pytest.raises(MissingDependencyError, match="--sam-checkpoint"):
        cli._check_photo_flags(args)


class _FakeSam:
    """A stand-in for `segment_anything` (no weights here): records what `sam_mask` asks of it and
    answers three masks whose scores make the second the best."""

    def __init__(self) -> None:
        self.calls: dict[str, object] = {}
        self.masks = np.zeros((3, 40, 60), dtype=bool)
        self.masks[1, 10:30, 15:45] = True
        self.sam_model_registry = {k: self._builder(k) for k in ("vit_h", "vit_l", "vit_b")}

    def _builder(self, kind: str):
        def build(checkpoint: str) -> str:
            self.calls["kind"], self.calls["checkpoint"] = kind, checkpoint
            return f"model-{kind}"

        return build

    def SamPredictor(self, model: str):
        fake = self

        class Predictor:
            def set_image(self, image: np.ndarray) -> None:
                fake.calls["image_shape"] = image.shape

            def predict(self, box: np.ndarray, multimask_output: bool):
                fake.calls["box"], fake.calls["multimask"] = tuple(box.tolist()), multimask_output
                return fake.masks, np.array([0.2, 0.9, 0.5]), None

        fake.calls["model"] = model
        return Predictor()


@pytest.fixture
def fake_sam(monkeypatch) -> _FakeSam:
    import sys
    import types

    fake = _FakeSam()
    module = types.ModuleType("segment_anything")
    module.SamPredictor = fake.SamPredictor  # type: ignore[attr-defined]
    module.sam_model_registry = fake.sam_model_registry  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "segment_anything", module)
    return fake


def test_sam_mask_refuses_a_missing_checkpoint(tmp_path, fake_sam: _FakeSam) -> None:
    from gaffer_diffusion.automask import sam_mask

    rgb, _ = _scene(40, 60)
    with pytest.raises(InputValueError, match=r"`--sam-checkpoint` .*sam_vit_b\.pth is not a file"):
        sam_mask(rgb, tmp_path / "sam_vit_b.pth")
    assert fake_sam.calls == {}  # refused before any model is built


def test_sam_mask_without_segment_anything_names_the_install(tmp_path, monkeypatch) -> None:
    import sys

    from gaffer_diffusion.automask import sam_mask

    monkeypatch.setitem(sys.modules, "segment_anything", None)  # import raises ImportError
    rgb, _ = _scene(40, 60)
    with pytest.raises(MissingDependencyError, match="pip install segment-anything"):
        sam_mask(rgb, tmp_path / "sam.pth")


@pytest.mark.parametrize(
    ("name", "kind"), [("sam_vit_b_01ec64.pth", "vit_b"), ("sam.pth", "vit_h")]
)
def test_sam_mask_prompts_the_centred_box_and_keeps_the_best_mask(
    tmp_path, fake_sam: _FakeSam, name: str, kind: str
) -> None:
    from gaffer_diffusion.automask import centred_box, sam_mask

    ckpt = tmp_path / name
    ckpt.write_bytes(b"not read by the fake")
    rgb, _ = _scene(40, 60)
    mask = sam_mask(rgb, ckpt)
    assert fake_sam.calls["kind"] == kind and fake_sam.calls["checkpoint"] == str(ckpt)
    assert fake_sam.calls["image_shape"] == (40, 60, 3)
    assert fake_sam.calls["box"] == centred_box(40, 60) and fake_sam.calls["multimask"] is True
    assert mask.dtype == np.float32 and np.array_equal(mask, fake_sam.masks[1])  # score 0.9 wins


@pytest.mark.weights
def test_sam_mask_with_segment_anything_and_real_weights() -> None:
    # Only this part needs SAM's weights (GAFFER_SAM_CHECKPOINT, a local .pth): none is downloaded here.
    import os

    pytest.importorskip("segment_anything", reason="segment-anything is not installed")
    ckpt = os.environ.get("GAFFER_SAM_CHECKPOINT")
    if not ckpt or not Path(ckpt).is_file():
        pytest.skip("set GAFFER_SAM_CHECKPOINT to a local Segment Anything checkpoint")
    from gaffer_diffusion.automask import sam_mask

    rgb, disc = _scene(150, 200)
    m = sam_mask(rgb, ckpt) > 0.5
    assert (m & disc).sum() / (m | disc).sum() > 0.9


def test_envmap_backdrop_looks_where_the_camera_looks() -> None:
    from gaffer_envmap.conventions import direction_grid
    from gaffer_envmap.poses import orbit_w2c_blender

    dirs = direction_grid(32, 64)  # world directions of a Blender lat-long map
    env = np.clip(dirs, 0, None).astype(np.float32)  # red where +x, green +y, blue +z (up)
    pose = orbit_w2c_blender(0.0, 0.0)
    view = envmap_backdrop(env, pose.rotation, height=12, width=16, fov_deg=40.0)
    centre_world = -pose.rotation[2]  # the camera looks down its -z
    rgb = view[6, 8] ** 2.2
    assert np.allclose(rgb, np.clip(centre_world, 0, None), atol=0.1)
    assert view[0, 8, 2] > view[-1, 8, 2]  # the top of the picture looks further up (+z)


# ----- the CLI around it -----


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("photo") / "model"
    assert main(["init-random", "--preset", "tiny", "--out", str(d)]) == 0
    return d


def _env(tmp_path: Path) -> Path:
    from gaffer_envmap import EnvironmentMap, write_envmap

    env = np.full((16, 32, 3), 0.3, np.float32)
    env[..., 0] += np.linspace(0.0, 0.6, 32, dtype=np.float32)  # redder towards one side
    env[4, 8] = 50.0
    write_envmap(tmp_path / "env.exr", EnvironmentMap(radiance_linear=env))
    return tmp_path / "env.exr"


def _args(tmp_path: Path, model_dir: Path, image: Path, *extra: str) -> list[str]:
    return [
        "relight",
        str(image),
        "--envmap",
        str(_env(tmp_path)),
        "--azimuth",
        "20",
        "--elevation",
        "10",
        "--checkpoint",
        str(model_dir),
        "--steps",
        "1",
        *extra,
    ]


def test_cli_relight_returns_the_photo_at_its_size(tmp_path, model_dir, capsys) -> None:
    rgb, disc = _scene(90, 130)
    image = _save(rgb, tmp_path / "p.jpg", quality=95)
    _save((disc * 255).astype(np.uint8), tmp_path / "m.png")
    args = _args(tmp_path, model_dir, image, "--mask", str(tmp_path / "m.png"))
    assert main([*args, "--out", str(tmp_path / "o.png")]) == 0
    out = np.asarray(Image.open(tmp_path / "o.png"))
    src = np.asarray(Image.open(image))
    assert out.shape == (90, 130, 3) and np.array_equal(out[~disc], src[~disc])
    assert "130x90, the input's size" in capsys.readouterr().out
    assert main([*args, "--out", str(tmp_path / "c.png"), "--output-size", "model"]) == 0
    assert np.asarray(Image.open(tmp_path / "c.png")).shape == (64, 64, 3)
    assert main([*args, "--out", str(tmp_path / "b.png"), "--background", "envmap"]) == 0
    back = np.asarray(Image.open(tmp_path / "b.png"))
    assert back.shape == (90, 130, 3) and not np.array_equal(back[~disc], src[~disc])
    spin = ["--background", "envmap", "--turntable", "2", "--video", "gif"]
    assert main([*args, "--out", str(tmp_path / "t.png"), *spin]) == 0
    f0, f1 = (np.asarray(Image.open(tmp_path / f"t_{k:03d}.png"), np.int16) for k in (0, 1))
    assert f0.shape == (90, 130, 3) and np.abs(f0 - f1)[~disc].max() > 0  # the backdrop turns


def test_cli_mask_auto_writes_the_mask_and_says_it_is_a_fallback(
    tmp_path, model_dir, capsys
) -> None:
    pytest.importorskip("cv2")
    rgb, _ = _scene(90, 130)
    image = _save(rgb, tmp_path / "p.png")
    args = _args(tmp_path, model_dir, image, "--mask", "auto", "--out", str(tmp_path / "o.png"))
    assert main(args) == 0
    said = capsys.readouterr().out
    assert "classical fallback" in said and f"--mask {tmp_path / 'o.mask.png'}" in said
    assert np.asarray(Image.open(tmp_path / "o.mask.png")).shape == (90, 130)
    assert main(["prepare", str(image), "--mask", "auto", "--out", str(tmp_path / "q.png")]) == 0
    assert (tmp_path / "q.mask.png").is_file() and (tmp_path / "q_mask.png").is_file()


def test_cli_input_errors_come_before_the_weights(tmp_path, model_dir, monkeypatch, capsys) -> None:
    def no_weights(*_a, **_k):
        raise AssertionError("weights were loaded before the input was checked")

    # the relight command's own reference (cli/relight.py), which it calls
    monkeypatch.setattr("gaffer_diffusion.cli.relight._load_model", no_weights)
    rgb, _ = _scene(40, 60)
    image = _save(rgb, tmp_path / "p.png")
    _save(np.zeros((30, 20), np.uint8), tmp_path / "small.png")
    _save(np.zeros((40, 60), np.uint8), tmp_path / "black.png")
    for mask, says in (("small.png", "20x30"), ("black.png", "all black")):
        args = _args(tmp_path, model_dir, image, "--mask", str(tmp_path / mask))
        assert main([*args, "--out", str(tmp_path / "o.png")]) == 2
        err = capsys.readouterr().err
        assert says in err and err.count("\n") == 1


def test_cli_folder_reports_a_failed_image_and_goes_on(tmp_path, model_dir, capsys) -> None:
    imgs = tmp_path / "imgs"
    imgs.mkdir()
    rgba = np.zeros((40, 30, 4), np.uint8)
    rgba[..., :3] = 100
    rgba[8:30, 5:25, 3] = 255
    _save(rgba, imgs / "good.png")
    (imgs / "broken.png").write_bytes(b"not a png")
    buf = io.BytesIO()
    Image.fromarray(rgba[..., :3]).save(buf, format="PNG")
    (imgs / "no_alpha.png").write_bytes(buf.getvalue())
    args = _args(tmp_path, model_dir, imgs, "--out", str(tmp_path / "out"))
    assert main(args) == 1
    captured = capsys.readouterr()
    assert "1/1" in captured.err  # the progress bar reached the end
    assert "broken.png" in captured.err and "no_alpha.png" in captured.err
    out = tmp_path / "out" / "good" / "env.png"
    assert np.asarray(Image.open(out)).shape == (40, 30, 4)
    assert not list((tmp_path / "out").rglob(".*tmp*"))  # atomic writes leave no temporary file


# ----- a photo without a usable alpha gets the automatic mask by default -----


def _no_alpha_photo(tmp_path: Path, kind: str) -> tuple[Path, np.ndarray]:
    rgb, disc = _scene(90, 130)
    if kind == "rgb-jpeg":
        return _save(rgb, tmp_path / "p.jpg", quality=95), disc
    opaque = np.dstack([rgb, np.full(rgb.shape[:2], 255, np.uint8)])  # RGBA, alpha all 255
    return _save(opaque, tmp_path / "p.png"), disc


@pytest.mark.parametrize("kind", ["rgb-jpeg", "opaque-rgba"])
def test_cli_relight_estimates_the_mask_of_a_photo_without_usable_alpha(
    tmp_path, model_dir, capsys, kind
) -> None:
    pytest.importorskip("cv2")
    image, disc = _no_alpha_photo(tmp_path, kind)
    assert main([*_args(tmp_path, model_dir, image), "--out", str(tmp_path / "o.png")]) == 0
    said = capsys.readouterr().out
    why = "has no alpha channel" if kind == "rgb-jpeg" else "is all opaque"
    assert why in said and "mask estimated" in said and "GrabCut" in said
    assert f"--mask {tmp_path / 'o.mask.png'}" in said  # how to pass a corrected one
    m = np.asarray(Image.open(tmp_path / "o.mask.png")) > 127
    assert m.shape == disc.shape and (m & disc).sum() / (m | disc).sum() > 0.8
    # `--mask PATH` still wins: no estimate, no mask written
    _save((disc * 255).astype(np.uint8), tmp_path / "m.png")
    args = _args(tmp_path, model_dir, image, "--mask", str(tmp_path / "m.png"))
    assert main([*args, "--out", str(tmp_path / "given.png")]) == 0
    assert "estimated" not in capsys.readouterr().out
    assert (tmp_path / "given.png").is_file() and not (tmp_path / "given.mask.png").exists()


def test_cli_estimated_mask_is_written_with_the_outputs_or_not_at_all(
    tmp_path, model_dir, monkeypatch, capsys
) -> None:
    pytest.importorskip("cv2")
    from gaffer_diffusion.errors import ConfigError

    image, _ = _no_alpha_photo(tmp_path, "rgb-jpeg")

    def fails(*_a, **_k):
        raise ConfigError("the model could not be loaded (a test)")

    monkeypatch.setattr("gaffer_diffusion.cli.relight._load_model", fails)
    assert main([*_args(tmp_path, model_dir, image), "--out", str(tmp_path / "o.png")]) == 2
    assert "a test" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("o")) == []
    spin = ["--turntable", "2", "--video", "gif", "--out", str(tmp_path / "t.png")]
    assert main([*_args(tmp_path, model_dir, image), *spin]) == 2
    assert not list(tmp_path.glob("t*"))


def test_cli_turntable_and_prepare_write_the_estimated_mask_beside_their_outputs(
    tmp_path, model_dir, capsys
) -> None:
    pytest.importorskip("cv2")
    image, _ = _no_alpha_photo(tmp_path, "opaque-rgba")
    spin = ["--turntable", "2", "--video", "gif", "--out", str(tmp_path / "t.png")]
    assert main([*_args(tmp_path, model_dir, image), *spin]) == 0
    assert {"t_000.png", "t_001.png", "t.gif", "t.mask.png"} <= {p.name for p in tmp_path.iterdir()}
    assert main(["prepare", str(image), "--out", str(tmp_path / "q.png"), "--size", "32"]) == 0
    assert (tmp_path / "q.png").is_file() and (tmp_path / "q_mask.png").is_file()
    assert (tmp_path / "q.mask.png").is_file() and "all opaque" in capsys.readouterr().out


def test_usable_alpha_ignores_an_all_opaque_alpha(tmp_path) -> None:
    from gaffer_diffusion.photo import usable_alpha

    rgb, disc = _scene(20, 30)
    opaque = read_photo(
        _save(np.dstack([rgb, np.full((20, 30), 255, np.uint8)]), tmp_path / "a.png")
    )
    cut = read_photo(_save(np.dstack([rgb, disc.astype(np.uint8) * 255]), tmp_path / "b.png"))
    assert usable_alpha(read_photo(_save(rgb, tmp_path / "c.png"))) is None
    assert usable_alpha(opaque) is None
    assert np.array_equal(usable_alpha(cut) > 0.5, disc)


def test_cli_normals_estimates_the_mask_of_an_rgb_photo(tmp_path, capsys) -> None:
    pytest.importorskip("cv2")
    image, disc = _no_alpha_photo(tmp_path, "rgb-jpeg")
    assert main(["normals", str(image), "--out", str(tmp_path / "n.png")]) == 0
    assert "has no alpha channel: mask estimated by GrabCut" in capsys.readouterr().out
    assert np.asarray(Image.open(tmp_path / "n.png")).shape == (*disc.shape, 3)
    assert np.asarray(Image.open(tmp_path / "n.mask.png")).shape == disc.shape


def test_app_engine_estimates_the_mask_of_an_all_opaque_photo_as_relight_does(tmp_path) -> None:
    pytest.importorskip("cv2")
    from gaffer_diffusion.app.config import AppConfig
    from gaffer_diffusion.app.engine import Engine

    engine = Engine(AppConfig())
    rgb, disc = _scene(90, 130)
    opaque, _ = _no_alpha_photo(tmp_path, "opaque-rgba")
    cut = _save(np.dstack([rgb, disc.astype(np.uint8) * 255]), tmp_path / "cut.png")
    assert not engine.has_alpha(_save(rgb, tmp_path / "rgb.png")) and not engine.has_alpha(opaque)
    assert engine.has_alpha(cut)
    prepared = engine.prepare(engine.model_labels[0], opaque, None)
    assert prepared.auto_mask and ((prepared.mask > 127) & disc).sum() > 0.8 * disc.sum()
    assert not engine.prepare(engine.model_labels[0], cut, None).auto_mask
