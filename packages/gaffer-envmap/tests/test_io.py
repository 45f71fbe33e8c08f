"""File I/O: atomic writes, EXR/HDR/PNG round trips, refusals with clear errors."""

import logging
import os
import sys
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from gaffer_envmap import _exr_header as exr_header
from gaffer_envmap import io_exr
from gaffer_envmap._exr_header import ExrCorruptError, validate_exr
from gaffer_envmap.atomic import atomic_write
from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.errors import (
    EnvmapReadError,
    EnvmapWriteError,
    HalfOverflowError,
    MissingDependencyError,
    NonFiniteError,
    ShapeError,
)
from gaffer_envmap.io import read_envmap, read_image_array, write_envmap, write_png
from gaffer_envmap.io_exr import read_exr, write_exr
from gaffer_envmap.io_hdr import read_hdr, write_hdr
from gaffer_envmap.io_ldr import decode_to_linear, read_ldr


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


def _radiance(rng: np.random.Generator, he: int = 16) -> np.ndarray:
    # log-uniform over 12 decades plus exact zeros: exercises every exponent range of float32
    x = np.exp(rng.uniform(-14, 14, (he, 2 * he, 3))).astype(np.float32)
    x[0, :3] = 0.0
    return x


# ------------------------------------------------------------------------------------------------
# atomic writes


def test_atomic_write_failure_keeps_old_file_and_leaves_no_temp(tmp_path: Path) -> None:
    dest = tmp_path / "map.exr"
    dest.write_bytes(b"old content")

    def half_then_fail(tmp: Path) -> None:
        tmp.write_bytes(b"new partial")
        raise RuntimeError("disk on fire")

    with pytest.raises(EnvmapWriteError, match=r"map\.exr") as info:
        atomic_write(dest, half_then_fail)
    assert isinstance(info.value.__cause__, RuntimeError)
    assert dest.read_bytes() == b"old content"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.exr"]


def test_atomic_write_interrupt_propagates_and_cleans_up(tmp_path: Path) -> None:
    def interrupted(tmp: Path) -> None:
        tmp.write_bytes(b"x")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        atomic_write(tmp_path / "a.exr", interrupted)
    assert list(tmp_path.iterdir()) == []


def test_atomic_write_replaces_and_keeps_permissions(tmp_path: Path) -> None:
    dest = tmp_path / "a.bin"
    dest.write_bytes(b"old")
    os.chmod(dest, 0o640)
    assert atomic_write(dest, lambda tmp: tmp.write_bytes(b"new")) == 3
    assert dest.read_bytes() == b"new"
    assert dest.stat().st_mode & 0o777 == 0o640
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bin"]


def test_atomic_write_missing_directory(tmp_path: Path) -> None:
    with pytest.raises(EnvmapWriteError, match="does not exist"):
        atomic_write(tmp_path / "nope" / "a.exr", lambda tmp: tmp.write_bytes(b""))


def test_exr_writer_failing_midway_keeps_old_file(
    tmp_path: Path, rng: np.random.Generator, monkeypatch: pytest.MonkeyPatch
) -> None:
    dest = tmp_path / "env.exr"
    old = _radiance(rng)
    write_envmap(dest, old)
    before = dest.read_bytes()

    class _FailingFile:
        def __init__(self, *args: object) -> None:
            pass

        def write(self, filename: str) -> None:
            Path(filename).write_bytes(b"v/1\x01 half an exr")
            raise RuntimeError("simulated crash while writing")

    class _FakeOpenEXR:
        def __getattr__(self, name: str) -> object:
            return getattr(OpenEXR, name)

        File = _FailingFile

    monkeypatch.setattr(io_exr, "_openexr", lambda: _FakeOpenEXR())
    with pytest.raises(EnvmapWriteError, match="simulated crash"):
        write_envmap(dest, _radiance(rng) * 2)
    assert dest.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["env.exr"]
    monkeypatch.undo()
    np.testing.assert_array_equal(read_envmap(dest).radiance_linear, old)


# ------------------------------------------------------------------------------------------------
# EXR


@pytest.mark.parametrize("compression", ["none", "rle", "zips", "zip", "piz"])
def test_exr_float32_round_trip_is_bit_exact(
    tmp_path: Path, rng: np.random.Generator, compression: str
) -> None:
    x = _radiance(rng)
    x[1, 1] = [
        np.finfo(np.float32).max,
        np.finfo(np.float32).tiny,
        1e-45,
    ]  # max, min normal, denormal
    path = tmp_path / "a.exr"
    write_envmap(path, x, compression=compression)
    y = read_envmap(path).radiance_linear
    assert y.dtype == np.float32
    assert np.array_equal(y.view(np.uint32), x.view(np.uint32))


def test_exr_nonfinite_and_negative_round_trip_bit_exact(tmp_path: Path) -> None:
    x = np.array([[[np.nan, np.inf, -np.inf], [-0.0, -3.5, 1.0]]], np.float32)
    write_exr(tmp_path / "a.exr", x)
    y = read_image_array(tmp_path / "a.exr")
    assert np.array_equal(y.view(np.uint32), x.view(np.uint32))


def test_exr_half_round_trip_within_half_precision(
    tmp_path: Path, rng: np.random.Generator
) -> None:
    x = (rng.random((16, 32, 3)) * 60000).astype(np.float32)
    x[0, 0] = [65504.0, 6.1e-5, 0.0]
    write_envmap(tmp_path / "h.exr", x, dtype="half")
    y = read_envmap(tmp_path / "h.exr").radiance_linear
    assert read_exr(tmp_path / "h.exr")[1]["exr_pixel_type"] == "half,half,half"
    np.testing.assert_array_equal(y, x.astype(np.float16).astype(np.float32))
    np.testing.assert_allclose(y, x, rtol=2.0**-11, atol=2.0**-24)


def test_half_overflow_raises_with_max_and_fix(tmp_path: Path) -> None:
    x = np.ones((4, 8, 3), np.float32)
    x[2, 3, 1] = 70000.0
    x[1, 1, 0] = -1e6
    with pytest.raises(HalfOverflowError) as info:
        write_envmap(tmp_path / "h.exr", x, dtype="half")
    msg = str(info.value)
    assert "2 finite value(s)" in msg and "1e+06" in msg
    assert 'overflow="clamp"' in msg and 'dtype="float32"' in msg
    assert not (tmp_path / "h.exr").exists()


def test_half_overflow_clamp_logs_count(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    x = np.ones((4, 8, 3), np.float32)
    x[2, 3, 1] = 70000.0
    x[1, 1, 0] = -1e6
    x[0, 0, 2] = np.inf  # non-finite values are not "overflow": written as they are
    with caplog.at_level(logging.WARNING, logger="gaffer_envmap.io_exr"):
        write_exr(tmp_path / "h.exr", x, dtype="half", overflow="clamp")
    assert any("clamping 2 value(s)" in r.getMessage() for r in caplog.records)
    y = read_image_array(tmp_path / "h.exr")
    assert y[2, 3, 1] == 65504.0 and y[1, 1, 0] == -65504.0 and np.isposinf(y[0, 0, 2])


def test_half_at_limit_does_not_overflow(tmp_path: Path) -> None:
    x = np.full((2, 4, 3), 65504.0, np.float32)
    write_envmap(tmp_path / "h.exr", x, dtype="half")
    assert read_image_array(tmp_path / "h.exr").max() == 65504.0


@pytest.mark.parametrize("fraction", [0.5, 0.9, 0.2, 0.02])
def test_truncated_exr_is_refused(
    tmp_path: Path, rng: np.random.Generator, fraction: float
) -> None:
    good = tmp_path / "good.exr"
    write_envmap(good, _radiance(rng, 32))
    data = good.read_bytes()
    bad = tmp_path / "bad.exr"
    bad.write_bytes(data[: int(len(data) * fraction)])
    with pytest.raises(EnvmapReadError, match=r"bad\.exr") as info:
        read_envmap(bad)
    assert "truncated" in str(info.value) or "outside the file" in str(info.value)


def test_empty_and_garbage_exr_are_refused(tmp_path: Path) -> None:
    (tmp_path / "empty.exr").write_bytes(b"")
    (tmp_path / "text.exr").write_bytes(b"#?RADIANCE\nthis is not an exr at all")
    with pytest.raises(EnvmapReadError, match="too short"):
        read_envmap(tmp_path / "empty.exr")
    with pytest.raises(EnvmapReadError, match="bad magic"):
        read_envmap(tmp_path / "text.exr")


def test_corrupt_offset_table_is_caught_by_the_validator(
    tmp_path: Path, rng: np.random.Generator
) -> None:
    path = tmp_path / "a.exr"
    write_envmap(path, _radiance(rng, 32))
    info = validate_exr(path)
    assert info.parts[0].chunk_count == 2  # 32 rows, 16 scan lines per ZIP chunk
    data = bytearray(path.read_bytes())
    reader = exr_header._Reader(bytes(data))
    exr_header._read_version(reader)
    exr_header._read_header(reader, 31)
    table = reader.pos  # the offset table follows the header
    assert int.from_bytes(data[table : table + 8], "little") == table + 16
    data[table : table + 8] = (10**12).to_bytes(8, "little")  # first chunk far outside the file
    path.write_bytes(bytes(data))
    with pytest.raises(ExrCorruptError, match="outside the file"):
        validate_exr(path)
    with pytest.raises(EnvmapReadError, match="refused before decoding"):
        read_envmap(path)


def test_exr_wrong_channels_are_refused(tmp_path: Path) -> None:
    uv = np.ones((4, 8), np.float32)
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, {"U": uv, "V": uv}).write(
        str(tmp_path / "uv.exr")
    )
    with pytest.raises(EnvmapReadError, match=r"no part with R, G, B .*\['U', 'V'\]"):
        read_envmap(tmp_path / "uv.exr")
    with pytest.raises(ShapeError, match=r"\[He, 2\*He, 3\]"):
        write_envmap(tmp_path / "x.exr", np.ones((4, 8, 2), np.float32))
    with pytest.raises(ShapeError, match="pixels"):
        write_exr(tmp_path / "x.exr", np.ones((4, 8, 2), np.float32))


def test_exr_luminance_reads_as_grey(tmp_path: Path, rng: np.random.Generator) -> None:
    y = rng.random((4, 8)).astype(np.float32)
    write_exr(tmp_path / "y.exr", y)
    env = read_envmap(tmp_path / "y.exr")
    for c in range(3):
        np.testing.assert_array_equal(env.radiance_linear[..., c], y)
    assert env.metadata["exr_channels"] == "Y"


def test_exr_alpha_dropped_for_envmaps_kept_for_arrays(
    tmp_path: Path, rng: np.random.Generator
) -> None:
    rgba = rng.random((4, 8, 4)).astype(np.float32)
    write_exr(tmp_path / "a.exr", rgba)
    np.testing.assert_array_equal(read_image_array(tmp_path / "a.exr"), rgba)
    np.testing.assert_array_equal(read_envmap(tmp_path / "a.exr").radiance_linear, rgba[..., :3])


def test_exr_multipart_uses_first_rgb_part(tmp_path: Path, rng: np.random.Generator) -> None:
    rgb = rng.random((4, 8, 3)).astype(np.float32)
    depth = OpenEXR.Part({"compression": OpenEXR.ZIP_COMPRESSION}, {"Z": rgb[..., 0] * 9}, "depth")
    beauty = OpenEXR.Part({"compression": OpenEXR.PIZ_COMPRESSION}, {"RGB": rgb}, "beauty")
    other = OpenEXR.Part({"compression": OpenEXR.ZIP_COMPRESSION}, {"RGB": rgb * 5}, "other")
    OpenEXR.File([depth, beauty, other]).write(str(tmp_path / "m.exr"))
    env = read_envmap(tmp_path / "m.exr")
    np.testing.assert_array_equal(env.radiance_linear, rgb)
    assert env.metadata["exr_part"] == "beauty"


def test_exr_metadata_envmap_and_convention(tmp_path: Path, rng: np.random.Generator) -> None:
    write_exr(tmp_path / "ll.exr", _radiance(rng), envmap="latlong", attributes={"owner": "me"})
    meta = read_envmap(tmp_path / "ll.exr", convention="openexr", alignment="corner").metadata
    assert meta["envmap"] == "latlong" and meta["owner"] == "me"
    env = EnvironmentMap(radiance_linear=_radiance(rng), convention="threejs")
    write_envmap(tmp_path / "e.exr", env)
    meta = read_envmap(tmp_path / "e.exr", convention="threejs").metadata
    assert meta["gaffer:convention"] == "threejs" and meta["gaffer:alignment"] == "center"
    assert "envmap" not in meta


def test_nonfinite_envmap_goes_through_sanitize(tmp_path: Path) -> None:
    x = np.ones((4, 8, 3), np.float32)
    x[1, 2, 0] = np.nan
    x[2, 2, 1] = np.inf
    x[3, 0, 2] = -1.0
    x[0, 0, 0] = 42.0
    write_envmap(tmp_path / "n.exr", x)
    with pytest.raises(NonFiniteError, match="1 NaN, 1 \\+Inf, 0 -Inf, 1 negative"):
        read_envmap(tmp_path / "n.exr")
    zero = read_envmap(tmp_path / "n.exr", sanitize="zero")
    assert zero.radiance_linear[2, 2, 1] == 0 and zero.metadata["sanitize"].startswith("zero")
    clamp = read_envmap(tmp_path / "n.exr", sanitize="clamp").radiance_linear
    assert clamp[2, 2, 1] == 42.0 and clamp[1, 2, 0] == 0 and clamp[3, 0, 2] == 0


def test_non_latlong_loads_as_array_but_not_as_envmap(tmp_path: Path) -> None:
    write_exr(tmp_path / "sq.exr", np.ones((8, 8, 3), np.float32))
    assert read_image_array(tmp_path / "sq.exr").shape == (8, 8, 3)
    with pytest.raises(ShapeError, match="twice as wide"):
        read_envmap(tmp_path / "sq.exr")
    write_exr(tmp_path / "cube.exr", np.ones((24, 4, 3), np.float32), envmap="cube")
    with pytest.raises(ShapeError, match="cube_to_latlong"):
        read_envmap(tmp_path / "cube.exr")


# ------------------------------------------------------------------------------------------------
# dispatch and refusals


def test_missing_file_names_path(tmp_path: Path) -> None:
    for name in ("nope.exr", "nope.hdr", "nope.png"):
        with pytest.raises(EnvmapReadError, match=f"{name}.*does not exist"):
            read_envmap(tmp_path / name)
    (tmp_path / "folder.exr").mkdir()
    with pytest.raises(EnvmapReadError, match="not a regular file"):
        read_envmap(tmp_path / "folder.exr")


def test_unknown_suffix_lists_supported(tmp_path: Path) -> None:
    (tmp_path / "a.tiff").write_bytes(b"II*\x00")
    with pytest.raises(EnvmapReadError, match=r"\.exr, \.hdr, \.png, \.jpg, \.jpeg"):
        read_envmap(tmp_path / "a.tiff")
    with pytest.raises(EnvmapWriteError, match=r"\.exr, \.hdr"):
        write_envmap(tmp_path / "a.tiff", np.ones((2, 4, 3), np.float32))
    with pytest.raises(EnvmapWriteError, match="write_png"):
        write_envmap(tmp_path / "a.png", np.ones((2, 4, 3), np.float32))


# ------------------------------------------------------------------------------------------------
# Radiance HDR


def test_hdr_round_trip(tmp_path: Path, rng: np.random.Generator) -> None:
    pytest.importorskip("OpenImageIO")
    x = (rng.random((8, 16, 3)) * 1000).astype(np.float32) + 1e-3
    write_envmap(tmp_path / "a.hdr", x)
    env = read_envmap(tmp_path / "a.hdr")
    # RGBE: 8-bit mantissas sharing the pixel's exponent -> error below 2^-7 of the pixel max
    err = np.abs(env.radiance_linear - x)
    assert (err <= x.max(axis=-1, keepdims=True) * 2.0**-7).all()
    assert env.metadata["format"] == "hdr"
    assert err.max() > 0  # RGBE really is lossy: the comparison above is not vacuous


def test_hdr_rejects_nonfinite_and_clamps_negative(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    pytest.importorskip("OpenImageIO")
    x = np.ones((2, 4, 3), np.float32)
    x[0, 0, 0] = np.nan
    with pytest.raises(NonFiniteError, match="RGBE"):
        write_hdr(tmp_path / "a.hdr", x)
    x[0, 0, 0] = -5.0
    with caplog.at_level(logging.WARNING, logger="gaffer_envmap.io_hdr"):
        write_hdr(tmp_path / "a.hdr", x)
    assert any("1 negative" in r.getMessage() for r in caplog.records)
    assert read_hdr(tmp_path / "a.hdr")[0, 0, 0] == 0.0


def test_truncated_hdr_is_refused(tmp_path: Path, rng: np.random.Generator) -> None:
    pytest.importorskip("OpenImageIO")
    write_hdr(tmp_path / "a.hdr", (rng.random((32, 64, 3)) * 10).astype(np.float32))
    data = (tmp_path / "a.hdr").read_bytes()
    (tmp_path / "b.hdr").write_bytes(data[: len(data) // 2])
    with pytest.raises(EnvmapReadError, match=r"b\.hdr"):
        read_envmap(tmp_path / "b.hdr")


def test_hdr_without_openimageio(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "a.hdr").write_bytes(b"#?RADIANCE\n")
    monkeypatch.setitem(sys.modules, "OpenImageIO", None)  # makes `import OpenImageIO` fail
    with pytest.raises(MissingDependencyError, match=r'pip install "gaffer-envmap\[hdr\]"'):
        read_envmap(tmp_path / "a.hdr")
    with pytest.raises(MissingDependencyError, match=r"gaffer-envmap\[hdr\]"):
        write_envmap(tmp_path / "b.hdr", np.ones((2, 4, 3), np.float32))


# ------------------------------------------------------------------------------------------------
# PNG / JPEG


def test_png_uint8_round_trip_exact(tmp_path: Path, rng: np.random.Generator) -> None:
    for shape in [(5, 7), (5, 7, 2), (5, 7, 3), (5, 7, 4)]:
        img = rng.integers(0, 256, shape, dtype=np.uint8)
        write_png(tmp_path / "a.png", img)
        back = read_ldr(tmp_path / "a.png")
        expected = img if img.ndim == 3 else img[..., None]
        np.testing.assert_array_equal(np.rint(back * 255).astype(np.uint8), expected)


def test_png_float_uses_round_to_nearest(tmp_path: Path) -> None:
    x = np.array([[[0.0, 0.9 / 255, 1.4 / 255], [0.5, 254.6 / 255, 1.0]]], np.float32)
    write_png(tmp_path / "a.png", x)
    stored = np.rint(read_image_array(tmp_path / "a.png") * 255).astype(int)
    assert stored.tolist() == [[[0, 1, 1], [128, 255, 255]]]  # truncation would give 0, 1, 127, 254


def test_png_float_is_clipped_and_nan_refused(tmp_path: Path) -> None:
    write_png(tmp_path / "a.png", np.array([[[-0.5, 0.5, 7.0]]], np.float32))
    assert np.rint(read_ldr(tmp_path / "a.png") * 255).astype(int).tolist() == [[[0, 128, 255]]]
    with pytest.raises(NonFiniteError):
        write_png(tmp_path / "b.png", np.array([[[np.nan, 0.5, 0.5]]]))
    with pytest.raises(ShapeError):
        write_png(tmp_path / "b.png", np.zeros((2, 2, 5), np.uint8))
    with pytest.raises(EnvmapWriteError, match=r"'\.png'"):
        write_png(tmp_path / "b.jpg", np.zeros((2, 2, 3), np.uint8))
    assert not (tmp_path / "b.png").exists()


@pytest.mark.parametrize(
    ("encoding", "expected"),
    [("srgb", 0.21586050), ("gamma2.2", (128 / 255) ** 2.2), ("linear", 128 / 255)],
)
def test_png_envmap_decodes_to_linear(tmp_path: Path, encoding: str, expected: float) -> None:
    write_png(tmp_path / "a.png", np.full((2, 4, 3), 128, np.uint8))
    env = read_envmap(tmp_path / "a.png", encoding=encoding)
    np.testing.assert_allclose(env.radiance_linear, expected, rtol=1e-6)
    assert env.metadata["encoding"] == encoding


def test_srgb_decode_matches_the_standard_curve() -> None:
    v = np.array([0.0, 0.04045, 0.5, 1.0])
    np.testing.assert_allclose(
        decode_to_linear(v, "srgb"), [0.0, 0.04045 / 12.92, 0.21404114, 1.0], rtol=1e-6
    )
    with pytest.raises(ValueError, match="`encoding`"):
        decode_to_linear(v, "rec709")  # type: ignore[arg-type]


def test_grey_png_envmap_and_jpeg(tmp_path: Path, rng: np.random.Generator) -> None:
    from PIL import Image

    grey = rng.integers(0, 256, (4, 8), dtype=np.uint8)
    write_png(tmp_path / "g.png", grey)
    env = read_envmap(tmp_path / "g.png", encoding="linear")
    np.testing.assert_allclose(env.radiance_linear[..., 1], grey / 255.0, rtol=1e-6)
    Image.fromarray(np.full((4, 8, 3), 200, np.uint8)).save(tmp_path / "a.jpg", quality=95)
    arr = read_image_array(tmp_path / "a.jpg")
    assert arr.shape == (4, 8, 3) and np.abs(arr - 200 / 255).max() < 3 / 255


def test_truncated_png_is_refused(tmp_path: Path, rng: np.random.Generator) -> None:
    write_png(tmp_path / "a.png", rng.integers(0, 256, (64, 128, 3), dtype=np.uint8))
    data = (tmp_path / "a.png").read_bytes()
    (tmp_path / "b.png").write_bytes(data[: len(data) // 2])
    with pytest.raises(EnvmapReadError, match=r"b\.png"):
        read_envmap(tmp_path / "b.png")
