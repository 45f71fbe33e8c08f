"""`gaffer_diffusion.images`: one 8-bit grid; PNG/GIF writing (`gaffer_envmap.writers`) is atomic.

A failure mid-write (the encoder raising after it wrote part of the file) must leave nothing under the
final name, an earlier file there untouched, and no temporary file beside it; the evaluation's saved
predictions and the validation sheet go through the same writer.
"""

from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from gaffer_diffusion import images
from gaffer_diffusion.evaluation import quantize_8bit as evaluation_quantize_8bit
from gaffer_envmap import writers


def _failing_save(monkeypatch: pytest.MonkeyPatch) -> None:
    """PIL's save writes some bytes to its target, then raises (a full disk, a kill mid-encode)."""

    def save(self: Image.Image, fp: object, *args: object, **kwargs: object) -> None:
        Path(str(fp)).write_bytes(b"\x89PNG\r\n\x1a\n partial")
        raise OSError("No space left on device")

    monkeypatch.setattr(Image.Image, "save", save)


def test_quantize_and_to_uint8_are_the_grid_the_old_copies_used() -> None:
    x = torch.rand(2, 3, 5, 7) * 1.2 - 0.1
    q = images.quantize_8bit(x)
    assert evaluation_quantize_8bit is images.quantize_8bit
    torch.testing.assert_close(q, (x.clamp(0, 1) * 255.0).round() / 255.0, rtol=0, atol=0)
    # validation rounded without clamping; the pipeline's images are in [0, 1], where both agree
    y = x.clamp(0, 1)
    torch.testing.assert_close(images.quantize_8bit(y), torch.round(y * 255.0) / 255.0)
    for img in (x[0], q[1]):
        old = (img.permute(1, 2, 0).clamp(0, 1).numpy() * 255.0).round().astype(np.uint8)
        np.testing.assert_array_equal(images.to_uint8(img), old)
    np.testing.assert_array_equal(
        images.to_uint8(q[0]).astype(np.float32) / 255.0, q[0].permute(1, 2, 0)
    )


def test_write_png_and_gif_round_trip(tmp_path: Path) -> None:
    arr = np.random.default_rng(0).integers(0, 256, (6, 5, 3), dtype=np.uint8)
    assert writers.write_png(tmp_path / "a.png", arr) == tmp_path / "a.png"
    np.testing.assert_array_equal(np.asarray(Image.open(tmp_path / "a.png")), arr)
    gif = writers.write_gif(tmp_path / "a.gif", [arr, 255 - arr], fps=25)
    with Image.open(gif) as im:
        assert (
            getattr(im, "n_frames", 1) == 2 and im.info["duration"] == 40 and im.info["loop"] == 0
        )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.gif", "a.png"]


@pytest.mark.parametrize("kind", ["png", "gif"])
def test_a_failure_mid_write_leaves_no_file_under_the_final_name(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, kind: str
) -> None:
    arr = np.zeros((4, 4, 3), np.uint8)
    old = tmp_path / f"old.{kind}"
    old.write_bytes(b"an earlier run's file")
    _failing_save(monkeypatch)
    for path in (tmp_path / f"new.{kind}", old):
        with pytest.raises(OSError, match="No space left"):
            if kind == "png":
                writers.write_png(path, arr)
            else:
                writers.write_gif(path, [arr, arr], fps=25)
    assert sorted(p.name for p in tmp_path.iterdir()) == [old.name]
    assert old.read_bytes() == b"an earlier run's file"


def test_saved_predictions_and_the_validation_sheet_are_written_atomically(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from gaffer_diffusion.evaluation.records import EncodedLightingFiles, EvalPair
    from gaffer_diffusion.evaluation.run import _save_predictions
    from gaffer_diffusion.training.validation import ValidationSet, _write_sheet, sheet_array

    pairs = [
        EvalPair(
            name=f"obj/000_0_to_{i:03d}",
            object_id="obj",
            view_index=0,
            target_lighting=i,
            input_image=tmp_path / "in.png",
            target_image=tmp_path / "gt.png",
            mask=None,
            lighting=EncodedLightingFiles(ldr=tmp_path / "l.png", hdr=tmp_path / "h.png"),
        )
        for i in range(2)
    ]
    pred = images.quantize_8bit(torch.rand(2, 3, 8, 8))
    valset = ValidationSet(
        input_images=torch.rand(2, 3, 8, 8),
        target_images=torch.rand(2, 3, 8, 8),
        envmaps=torch.zeros(0, 0, 0, 3),
        w2c_blender=torch.zeros(2, 3, 4),
        names=("obj/0", "obj/1"),
    )
    # written: the same pixels as before
    _save_predictions(tmp_path / "pred", pairs, pred)
    for p, img in zip(pairs, pred, strict=True):
        saved = np.asarray(Image.open(tmp_path / "pred" / f"{p.name}.png"))
        np.testing.assert_array_equal(saved, (img.permute(1, 2, 0).numpy() * 255).round())
    sheet = _write_sheet(tmp_path / "sheets" / "step-00000001.png", valset, pred)
    np.testing.assert_array_equal(np.asarray(Image.open(sheet)), sheet_array(valset, pred))

    # a failure mid-write: nothing new under the final names, the earlier files untouched
    before = {p: p.read_bytes() for p in tmp_path.rglob("*.png")}
    _failing_save(monkeypatch)
    with pytest.raises(OSError, match="No space left"):
        _save_predictions(tmp_path / "pred2", pairs, pred)
    with pytest.raises(OSError, match="No space left"):
        _save_predictions(tmp_path / "pred", pairs, pred)
    with pytest.raises(OSError, match="No space left"):
        _write_sheet(tmp_path / "sheets" / "step-00000002.png", valset, pred)
    with pytest.raises(OSError, match="No space left"):
        _write_sheet(sheet, valset, pred)
    after = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    assert after == before


def test_srgb_transfer_round_trips_and_clips() -> None:
    from gaffer_diffusion.images import linear_to_srgb, srgb_to_linear

    x = torch.linspace(0.0, 1.0, 257)
    torch.testing.assert_close(linear_to_srgb(srgb_to_linear(x)), x, rtol=0, atol=1e-5)
    # IEC 61966-2-1 reference points: the linear segment and mid grey
    assert abs(float(srgb_to_linear(torch.tensor(0.04))) - 0.04 / 12.92) < 1e-7
    assert abs(float(srgb_to_linear(torch.tensor(0.5))) - 0.21404) < 1e-4
    assert float(srgb_to_linear(torch.tensor(1.5))) == 1.0
    assert float(linear_to_srgb(torch.tensor(-0.2))) == 0.0
