"""Converting the authors' released layout into a gaffer artifact, and reading it back (no bpy)."""

import json
from pathlib import Path

import numpy as np
import pytest

from gaffer_data.cli import main
from gaffer_data.convert import ConvertOptions, convert_authors, png_shape
from gaffer_data.dataset.authors import open_authors_dataset, read_authors_object
from gaffer_data.errors import InputError, IntegrityError, SchemaVersionError
from gaffer_envmap.poses import W2CBlender, orbit_w2c_blender


def _png(path: Path, value: int, size: int = 8, channels: int = 4) -> Path:
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    arr = np.full((size, size, channels), value, np.uint8)
    Image.fromarray(arr, mode="RGBA" if channels == 4 else "RGB").save(path)
    return path


def _fake_release(root: Path) -> tuple[Path, Path]:
    """A split with objects `a` (maps in a separate lighting folder), `b` (maps inside, HDR_normalized),
    `c` (an image without lighting maps) and a folder without poses (not an object)."""
    split, lighting = root / "val_unseen", root / "val_lighting"
    for name in ("a", "b", "c"):
        obj = split / name
        for v in range(2):
            obj.mkdir(parents=True, exist_ok=True)
            np.save(obj / f"{v:03d}_RT.npy", orbit_w2c_blender(90.0 * v, 20.0, 2.0).matrix)
            _png(obj / f"random_lighting_{v:03d}.png", 200 + v)
            for li, env in enumerate(("cannon_2k_225", "sky_1k_000")):
                image = _png(obj / f"{v:03d}_{li:03d}_{env}.png", 10 * v + li)
                if name == "a":
                    _png(lighting / "LDR" / name / image.name, 100 + li, 16, 3)
                    _png(lighting / "HDR_rescaled" / name / image.name, 150 + li, 16, 3)
                elif name == "b":
                    _png(obj / "LDR" / image.name, 100 + li, 16, 3)
                    _png(obj / "HDR_normalized" / image.name, 150 + li, 16, 3)
    (split / "notes").mkdir()
    (split / "notes" / "readme.txt").write_text("not an object")
    return split, lighting


def test_convert_and_read_back(tmp_path: Path) -> None:
    split, lighting = _fake_release(tmp_path)
    out = tmp_path / "out"
    summary = convert_authors(split, out, ConvertOptions(lighting=lighting))
    assert summary.converted == ("a", "b") and summary.images == 8
    assert [f.object_id for f in summary.failed] == ["c"]
    assert "LDR" in summary.failed[0].reason and "--lighting" in summary.failed[0].reason
    assert not (out / "objects" / "c").exists()

    ds = open_authors_dataset(out)
    assert ds.object_ids == ("a", "b") and [f.object_id for f in ds.skipped] == ["c"]
    assert ds.envmap_names == ("cannon_2k_225", "sky_1k_000")
    a = read_authors_object(out / "objects" / "a", verify=True)
    assert a.hdr_folder == "HDR_rescaled" and ds.object("b").hdr_folder == "HDR_normalized"
    assert a.intrinsics.width == 8 and np.isclose(a.intrinsics.fx, 35 / 32 * 8)
    assert {f.kind for f in a.files} == {
        "cameras",
        "lit_png",
        "area_png",
        "envmap_ldr",
        "envmap_hdr",
    }
    lit = next(f for f in a.files if f.path == "lit/001_000.png")
    assert lit.shape == (8, 8, 4) and lit.dtype == "uint8"
    assert next(f for f in a.files if f.kind == "envmap_hdr").shape == (16, 16, 3)

    samples = list(ds.iter_samples())
    assert len(samples) == 8
    s = next(
        x for x in samples if x.object_id == "a" and x.view_index == 1 and x.lighting_index == 0
    )
    assert s.envmap_name == "cannon_2k_225"
    assert s.image_png.read_bytes() == (split / "a" / "001_000_cannon_2k_225.png").read_bytes()
    assert (
        s.envmap_ldr.read_bytes()
        == (lighting / "LDR" / "a" / "001_000_cannon_2k_225.png").read_bytes()
    )
    assert s.area_png is not None
    assert s.area_png.read_bytes() == (split / "a" / "random_lighting_001.png").read_bytes()
    released = np.load(split / "a" / "001_RT.npy")
    np.testing.assert_array_equal(s.w2c_blender, released)
    np.testing.assert_allclose(
        s.c2w_opencv, W2CBlender(released).to_c2w_opencv().matrix, atol=1e-12
    )
    # OpenCV +z of the camera looks at the origin (the authors' cameras track it).
    to_origin = -s.c2w_opencv[:3, 3] / np.linalg.norm(s.c2w_opencv[:3, 3])
    np.testing.assert_allclose(s.c2w_opencv[:3, 2], to_origin, atol=1e-9)


def test_rerun_skips_converted_objects_and_verify_catches_corruption(tmp_path: Path) -> None:
    split, lighting = _fake_release(tmp_path)
    out = tmp_path / "out"
    convert_authors(split, out, ConvertOptions(lighting=lighting, object_ids=("a",)))
    manifest = out / "objects" / "a" / "manifest.json"
    before = manifest.stat().st_mtime_ns
    again = convert_authors(split, out, ConvertOptions(lighting=lighting, hardlink=True))
    assert again.skipped_complete == ("a",) and again.converted == ("b",)
    assert manifest.stat().st_mtime_ns == before
    b = read_authors_object(out / "objects" / "b", verify=True)
    assert (b.path("lit/000_000.png")).stat().st_nlink == 2  # hard-linked
    (out / "objects" / "a" / "lit" / "000_001.png").write_bytes(b"x")
    with pytest.raises(IntegrityError, match="000_001"):
        read_authors_object(out / "objects" / "a", verify=True)


def test_bad_inputs_are_named(tmp_path: Path) -> None:
    split, lighting = _fake_release(tmp_path)
    with pytest.raises(InputError, match="src"):
        convert_authors(tmp_path / "missing", tmp_path / "out")
    with pytest.raises(InputError, match="object_ids"):
        convert_authors(split, tmp_path / "out", ConvertOptions(object_ids=("zzz",)))
    with pytest.raises(InputError, match=r"RT\.npy"):
        convert_authors(split / "notes", tmp_path / "out")
    (split / "a" / "001_RT.npy").unlink()
    np.save(split / "b" / "000_RT.npy", np.eye(4)[:3] * 2.0)
    summary = convert_authors(split, tmp_path / "out", ConvertOptions(lighting=lighting))
    reasons = {f.object_id: f.reason for f in summary.failed}
    assert "[1]" in reasons["a"] and "world-to-camera" in reasons["b"]
    with pytest.raises(InputError, match="not a PNG"):
        png_shape(split / "notes" / "readme.txt")
    with pytest.raises(SchemaVersionError):
        from gaffer_data.dataset import open_dataset

        (tmp_path / "out" / "objects").mkdir(exist_ok=True)
        data = json.loads((tmp_path / "out" / "dataset.json").read_text())
        (tmp_path / "render").mkdir()
        (tmp_path / "render" / "dataset.json").write_text(json.dumps(data))
        open_dataset(tmp_path / "render")  # a converted dataset is not a render dataset


def test_cli_convert_authors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    split, _ = _fake_release(tmp_path)
    (tmp_path / "list.json").write_text(json.dumps(["b"]))
    code = main(
        ["convert-authors", str(split), "--out", str(tmp_path / "o"), "--object-list",
         str(tmp_path / "list.json")]
    )  # fmt: skip
    assert code == 0 and "converted 1 objects (4 images)" in capsys.readouterr().out
    code = main(["convert-authors", str(split), "--out", str(tmp_path / "o2")])
    assert code == 1  # a and c have their maps elsewhere: reported, not fatal
    assert open_authors_dataset(tmp_path / "o2").object_ids == ("b",)
