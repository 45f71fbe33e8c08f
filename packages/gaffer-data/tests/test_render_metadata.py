"""Volatile image metadata (dates, timings) is stripped without touching pixels (no Blender needed)."""

from pathlib import Path

import numpy as np
import pytest

from gaffer_data.render._metadata import is_volatile_key, strip_volatile_metadata

OpenEXR = pytest.importorskip("OpenEXR")
Image = pytest.importorskip("PIL.Image")
PngImagePlugin = pytest.importorskip("PIL.PngImagePlugin")

STAMPS = {
    "Date": "2026/12/02 15:31:28",
    "RenderTime": "00:00.02",
    "cycles.ViewLayer.render_time": "00:00.01",
    "cycles.ViewLayer.total_time": "00:00.02",
    "cycles.ViewLayer.samples": "4",
    "Software": "Blender 5.0.1",
}


def test_volatile_keys() -> None:
    volatile = {k for k in STAMPS if is_volatile_key(k)}
    assert volatile == {
        "Date",
        "RenderTime",
        "cycles.ViewLayer.render_time",
        "cycles.ViewLayer.total_time",
    }


def _write_exr(path: Path, stamps: dict[str, str]) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)
    channels = {c: rng.random((5, 7), dtype=np.float32) for c in "RGBA"}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, **stamps}
    with OpenEXR.File(header, dict(channels)) as f:  # the binding fills the dict it is given
        f.write(str(path))
    return channels


def test_exr_loses_only_the_volatile_attributes(tmp_path: Path) -> None:
    channels = _write_exr(tmp_path / "a.exr", STAMPS)
    assert strip_volatile_metadata(tmp_path / "a.exr")
    with OpenEXR.File(str(tmp_path / "a.exr"), separate_channels=True) as f:
        header = dict(f.header())
        pixels = {k: np.array(v.pixels) for k, v in f.channels().items()}
    assert not [k for k in header if is_volatile_key(k)]
    assert header["Software"] == "Blender 5.0.1" and header["cycles.ViewLayer.samples"] == "4"
    assert header["compression"] == OpenEXR.ZIP_COMPRESSION
    assert sorted(pixels) == sorted(channels)
    for name, values in channels.items():
        assert pixels[name].dtype == np.float32
        np.testing.assert_array_equal(pixels[name], values)
    # stripping is a function of the content: two files that differ only in their dates agree after
    _write_exr(tmp_path / "b.exr", {**STAMPS, "Date": "2027/01/01 00:00:00"})
    strip_volatile_metadata(tmp_path / "b.exr")
    assert (tmp_path / "a.exr").read_bytes() == (tmp_path / "b.exr").read_bytes()
    before = (tmp_path / "a.exr").read_bytes()
    assert not strip_volatile_metadata(tmp_path / "a.exr")
    assert (tmp_path / "a.exr").read_bytes() == before


def _write_png(path: Path, stamps: dict[str, str]) -> np.ndarray:
    rgba = np.random.default_rng(1).integers(0, 256, (6, 4, 4), dtype=np.uint8)
    info = PngImagePlugin.PngInfo()
    for key, value in stamps.items():
        info.add_text(key, value)
    Image.fromarray(rgba, mode="RGBA").save(path, format="PNG", pnginfo=info)
    return rgba


def test_png_loses_only_the_volatile_text_chunks(tmp_path: Path) -> None:
    rgba = _write_png(tmp_path / "a.png", STAMPS)
    _write_png(tmp_path / "bare.png", {k: v for k, v in STAMPS.items() if not is_volatile_key(k)})
    assert strip_volatile_metadata(tmp_path / "a.png")
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "bare.png").read_bytes()
    with Image.open(tmp_path / "a.png") as im:
        im.load()
        assert not [k for k in im.info if is_volatile_key(k)]
        assert im.info["Software"] == "Blender 5.0.1"
        np.testing.assert_array_equal(np.array(im), rgba)
    before = (tmp_path / "a.png").read_bytes()
    assert not strip_volatile_metadata(tmp_path / "a.png")
    assert (tmp_path / "a.png").read_bytes() == before


def test_other_files_are_left_alone(tmp_path: Path) -> None:
    path = tmp_path / "x.json"
    path.write_text("{}", encoding="utf-8")
    assert not strip_volatile_metadata(path)
    assert path.read_text(encoding="utf-8") == "{}"
