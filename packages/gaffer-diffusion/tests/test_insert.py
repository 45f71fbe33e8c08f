"""`gaffer-diffusion insert`: an object photo relit under a background's lighting,
placed by `--at` / `--height`, with a pixel-height shadow; the rest of the background byte for byte.

The background is a perspective view of a bundled HDRI (what a camera at the map's centre sees), the
object the shipped example photo; the model is the shipped gaffer-tiny (about a second on a CPU)."""

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from gaffer_diffusion import insert as ins
from gaffer_diffusion import pretrained
from gaffer_diffusion.cli import main
from gaffer_diffusion.photo import (
    RelitObject,
    envmap_backdrop,
    object_alpha,
    read_photo,
)
from gaffer_envmap.bundled import read_bundled_hdri
from gaffer_envmap.io import read_envmap
from gaffer_envmap.stats import total_power

W, H = 200, 150
OBJECT = pretrained.example_dataset_path() / "objects" / "procedural_002" / "lit" / "000_000.png"


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("insert")
    env = read_bundled_hdri("courtyard")
    view = envmap_backdrop(env.radiance_linear, ins.LEVEL_CAMERA.rotation, height=H, width=W)
    Image.fromarray(np.round(view * 255).astype(np.uint8)).save(tmp / "bg.png")
    Image.fromarray(np.zeros((10, 10), np.uint8)).save(tmp / "small_mask.png")
    (tmp / "text.exr").write_text("not an EXR\n")
    return {"bg": tmp / "bg.png", "small_mask": tmp / "small_mask.png", "text": tmp / "text.exr"}


def _run(files, out: Path, *extra: str) -> int:
    return main(["insert", str(OBJECT), "--into", str(files["bg"]), "--out", str(out), *extra])


def _read(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB"))


def _identity_relit() -> tuple[RelitObject, ins.ObjectExtent]:
    """The object photo itself as the 'relit' object (no model), over its whole frame."""
    photo = read_photo(OBJECT)
    alpha = object_alpha(photo, None)
    h, w = alpha.shape
    relit = RelitObject(box=(0, 0, h, w), rgb=photo.rgb, alpha=alpha)
    return relit, ins.object_extent(alpha)


# ----- placement -----


def test_placement_puts_the_lowest_centre_point_at_at_and_scales_to_height() -> None:
    relit, extent = _identity_relit()
    for at, height in [((100, 120), 60.0), ((40.0, 149.0), 25.0), ((150, 80), 80.0)]:
        placement = ins.resolve_placement((W, H), extent, at_xy=at, height_px=height)
        placed = ins.place_object(relit, extent, placement, (H, W))
        full = placed.full_alpha(H, W)
        rows, cols = np.nonzero(full > 0.5)
        assert rows.max() == at[1], (at, rows.max())  # its lowest row lands on row Y
        assert abs((rows.max() + 1 - rows.min()) - height) <= 1.0
        assert abs((cols.min() + cols.max() + 1) / 2 - (at[0] + 0.5)) <= 1.0
        assert (full[: max(int(at[1] + 1 - height) - 3, 0)] == 0).all()  # nothing above its top


def test_defaults_are_the_bottom_third_and_the_photo_height() -> None:
    _, extent = _identity_relit()
    placement = ins.resolve_placement((W, H), extent)
    assert placement.foot_xy == (100.0, 125.0)  # centre of the bottom third
    assert placement.height_px == extent.height
    assert "--at 100,125" in placement.chosen and "--height" in placement.chosen


@pytest.mark.parametrize(
    ("at", "height", "flag"),
    [((200, 10), None, "`--at`"), ((-1, 10), None, "`--at`"), ((100, 140), 500.0, "`--height`"),
     ((3, 140), 100.0, "`--height`"), ((100, 140), 1.0, "`--height`")],
)  # fmt: skip
def test_placements_that_do_not_fit_are_refused(at, height, flag) -> None:
    _, extent = _identity_relit()
    with pytest.raises(ValueError, match=flag):
        ins.resolve_placement((W, H), extent, at_xy=at, height_px=height)


# ----- lighting -----


def test_light_from_photo_adds_the_key_light_with_its_exact_power() -> None:
    rgb = _bg_rgb()
    camera = ins.BackgroundCamera(width=W, height=H)
    plain = ins.light_from_photo(rgb, camera)
    key = ins.KeyLight(azimuth_deg=135.0, elevation_deg=40.0, strength=3.0, size_deg=5.0)
    lit = ins.light_from_photo(rgb, camera, key)
    assert lit.radiance_linear.shape == (128, 256, 3) and lit.convention == "blender"
    mean_lum = float(total_power(plain) @ np.array([0.2126, 0.7152, 0.0722])) / (4 * math.pi)
    added = total_power(lit) - total_power(plain)
    np.testing.assert_allclose(added, 3.0 * math.pi * mean_lum, rtol=1e-4)
    light = ins.dominant_light(lit, key)
    np.testing.assert_allclose(light.direction_world, key.direction)
    assert 0.3 < light.share < 1.0
    # the photo is where the camera looks: world +y (u = 0.25, column 64) on the horizon (row 64)
    from gaffer_diffusion.detail_transfer import srgb_to_linear

    centre = ins.inverse_tone(srgb_to_linear(rgb[H // 2 - 2 : H // 2 + 2, W // 2 - 2 : W // 2 + 2]))
    np.testing.assert_allclose(
        plain.radiance_linear[63:65, 63:65].mean((0, 1)), centre.mean((0, 1)), rtol=0.25
    )


def _bg_rgb() -> np.ndarray:
    env = read_bundled_hdri("courtyard")
    return envmap_backdrop(env.radiance_linear, ins.LEVEL_CAMERA.rotation, height=H, width=W)


def test_dominant_light_of_a_map_finds_its_sun() -> None:
    env = read_bundled_hdri("courtyard")
    light = ins.dominant_light(env)
    assert light.direction_world[2] > 0.3 and 0.2 < light.share < 1.0
    key = ins.KeyLight(azimuth_deg=0.0, elevation_deg=0.0)
    assert np.allclose(key.direction, [0.0, 1.0, 0.0])
    with pytest.raises(ValueError, match="--key-light"):
        ins.KeyLight(azimuth_deg=0.0, elevation_deg=95.0)


# ----- shadow -----


def _placed(at=(100, 130), height=60.0) -> ins.PlacedObject:
    relit, extent = _identity_relit()
    placement = ins.resolve_placement((W, H), extent, at_xy=at, height_px=height)
    return ins.place_object(relit, extent, placement, (H, W))


def _columns(placed: ins.PlacedObject) -> tuple[int, int]:
    """First and last background column the placed object covers."""
    cols = np.nonzero(placed.full_alpha(H, W).any(0))[0]
    return int(cols.min()), int(cols.max())


def _shadow_for(azimuth: float, elevation: float = 35.0) -> np.ndarray:
    key = ins.KeyLight(azimuth_deg=azimuth, elevation_deg=elevation)
    light = ins.DominantLight(direction_world=key.direction, share=0.6, size_deg=5.0, source="k")
    return ins.cast_shadow_2d(_placed(), ins.BackgroundCamera(width=W, height=H), light)


def test_the_shadow_falls_away_from_the_key_light_and_moves_with_it() -> None:
    first, last = _columns(_placed())  # the object's columns (about 64..136), rows 71..130
    from_right, from_left = _shadow_for(90.0), _shadow_for(270.0)
    dark_r, dark_l = 1 - from_right, 1 - from_left
    left, right = np.s_[:, : first - 4], np.s_[:, last + 5 :]  # either side of the object
    assert dark_r[left].sum() > 10 * dark_r[right].sum() and dark_r[left].max() > 0.3
    assert dark_l[right].sum() > 10 * dark_l[left].sum() and dark_l[right].max() > 0.3
    # a light behind the object (in front of the camera) throws the shadow towards the camera
    behind = 1 - _shadow_for(0.0)
    below = behind[131:]
    assert below.sum() > 0 and below.max() > 0.3
    # an overhead light: only a pool under the foot; a light below the horizon: no cast shadow
    overhead = 1 - _shadow_for(0.0, 90.0)
    assert overhead[:, : first - 4].sum() == 0 and overhead[:, last + 5 :].sum() == 0
    assert np.array_equal(_shadow_for(90.0, -10.0) < 1, _shadow_for(270.0, -10.0) < 1)
    for dark in (dark_r, dark_l, behind):
        assert dark.min() >= 0 and (dark[:75] == 0).all()  # nothing above the horizon (row 75)


# ----- the command line, end to end -----


def test_cli_insert_keeps_the_background_bytes_away_from_the_object_and_its_shadow(
    files, tmp_path, capsys
) -> None:
    bg = _read(files["bg"])
    out = tmp_path / "o.png"
    assert _run(files, out, "--at", "100,130", "--height", "60", "--key-light", "90,35") == 0
    said = capsys.readouterr().out
    assert "object 60 px tall, its lowest point at 100,130" in said and "key light" in said
    img = _read(out)
    assert img.shape == bg.shape
    changed = (img != bg).any(-1)
    rows, cols = np.nonzero(changed)
    assert changed.sum() > 500
    # the object spans rows 71..130 and columns first..last; its shadow falls left (key from the
    # right) on the ground below the horizon (row 75): nothing changes above the object, right of
    # it, or far from it
    first, last = _columns(_placed())
    assert rows.min() >= 69 and cols.max() <= last + 1 and changed[:69].sum() == 0
    assert changed[:, last + 2 :].sum() == 0
    ground = np.s_[100:145, 5 : first - 2]
    assert (img[ground].astype(int) - bg[ground].astype(int)).sum() < 0  # the shadow darkens
    # moving the key light to the left moves the shadow to the right
    out2 = tmp_path / "o2.png"
    assert _run(files, out2, "--at", "100,130", "--height", "60", "--key-light", "270,35") == 0
    img2 = _read(out2)
    changed2 = (img2 != bg).any(-1)
    assert changed2[:, : first - 1].sum() == 0 and changed2[:, last + 2 :].sum() > 100


def test_cli_save_envmap_round_trips(files, tmp_path) -> None:
    a, env = tmp_path / "a.png", tmp_path / "light.exr"
    common = ["--at", "100,130", "--height", "60", "--shadow", "none"]
    assert _run(files, a, *common, "--key-light", "135,40", "--save-envmap", str(env)) == 0
    saved = read_envmap(env)
    assert saved.radiance_linear.shape == (128, 256, 3) and saved.convention == "blender"
    # the saved map is the lighting used: relighting under it gives the same picture
    b = tmp_path / "b.png"
    assert _run(files, b, *common, "--envmap", str(env)) == 0
    assert np.array_equal(_read(a), _read(b))
    # a map saved in another folder than the picture is the same map
    other = tmp_path / "maps" / "light.exr"
    assert (
        _run(files, tmp_path / "c.png", *common, "--envmap", str(env), "--save-envmap", str(other))
        == 0
    )
    np.testing.assert_array_equal(read_envmap(other).radiance_linear, saved.radiance_linear)
    # with shadow none only the object's pixels change
    changed = (_read(a) != _read(files["bg"])).any(-1)
    covered = _placed().full_alpha(H, W) > 0
    assert not (changed & ~covered).any() and changed.sum() > 0.8 * covered.sum()


def test_cli_with_an_envmap_and_detail_resize(files, tmp_path) -> None:
    out = tmp_path / "e.png"
    assert _run(files, out, "--envmap", "courtyard", "--detail", "resize", "--height", "50") == 0
    assert _read(out).shape == (H, W, 3)


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--mask", "{small_mask}"], "`--mask`"),
        (["--at", "500,10"], "`--at`"),
        (["--at", "100,140", "--height", "400"], "`--height` 141 or less"),
        (["--envmap", "{text}"], "`--envmap`"),
        (["--envmap", "courtyard", "--key-light", "10,20"], "`--key-light`"),
        (["--key-light", "10,20,-1"], "`--key-light`"),
        (["--fov", "0"], "`--fov`"),
        (["--save-envmap", "e.png"], "`--save-envmap`"),
    ],
)
def test_cli_refusals_are_one_line_before_the_model_loads(
    files, tmp_path, monkeypatch, capsys, extra, words
) -> None:
    import gaffer_diffusion.cli.insert as cli_insert

    def no_model(*_a: object) -> None:
        raise AssertionError("the model was loaded")

    monkeypatch.setattr(cli_insert, "_load_model", no_model)
    monkeypatch.chdir(tmp_path)
    argv = [a.format(**{k: str(v) for k, v in files.items()}) for a in extra]
    assert _run(files, tmp_path / "o.png", *argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # nothing written


def test_cycles_without_bpy_names_the_fallback(files, tmp_path, monkeypatch, capsys) -> None:
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "bpy" else real(name, *a)
    )
    assert _run(files, tmp_path / "o.png", "--shadow", "cycles") == 2
    err = capsys.readouterr().err
    assert "bpy" in err and "`--shadow 2d`" in err and not (tmp_path / "o.png").exists()


def test_insert_object_library_result(files) -> None:
    """The library call the CLI makes: typed result, shadow factor 1 wherever bytes are kept."""
    from gaffer_diffusion.demo import load_model
    from gaffer_diffusion.photo import prepare_photo
    from gaffer_diffusion.pipelines import RelightPipeline, SamplingConfig

    model = load_model(None).model
    photo = read_photo(OBJECT)
    prepared = prepare_photo(photo, object_alpha(photo, None), size=model.config.resolution)
    background = read_photo(files["bg"])
    camera = ins.BackgroundCamera(width=W, height=H)
    key = ins.KeyLight(azimuth_deg=200.0, elevation_deg=50.0)
    lighting = ins.InsertLighting(
        envmap=ins.light_from_photo(background.rgb, camera, key), camera=camera, key_light=key
    )
    placement = ins.resolve_placement((W, H), ins.object_extent(prepared.alpha), height_px=50.0)
    result = ins.insert_object(
        RelightPipeline(model),
        SamplingConfig(num_inference_steps=1, guidance_scale=1.0),
        prepared=prepared,
        background=background,
        lighting=lighting,
        placement=placement,
    )
    assert result.image.shape == (H, W, 3) and result.image.dtype == np.uint8
    keep = (result.shadow == 1.0) & (result.placed.full_alpha(H, W) == 0)
    assert np.array_equal(result.image[keep], background.rgb_u8[keep])
    assert (result.shadow < 1).any() and torch.isfinite(result.relit_model).all()
    import gaffer_diffusion.insert_shadow_cycles as cyc

    def sample_nothing(*_a: object, **_k: object) -> None:
        raise AssertionError("sampled before refusing")

    with pytest.MonkeyPatch.context() as mp:  # no bpy: refused before sampling, naming the fallback
        mp.setattr(cyc, "bpy_available", lambda: False)
        mp.setattr(ins, "relight_under", sample_nothing)
        with pytest.raises(ImportError, match="--shadow 2d"):
            ins.insert_object(
                RelightPipeline(model),
                SamplingConfig(num_inference_steps=1, guidance_scale=1.0),
                prepared=prepared,
                background=background,
                lighting=lighting,
                placement=placement,
                config=ins.InsertConfig(shadow="cycles"),
            )


def test_the_map_from_a_photo_mirrors_it_at_its_edges() -> None:
    """Just above the frame the sphere shows the photo's top, just below its bottom, just right of it
    its right edge; behind the camera both sides meet (no seam)."""
    rgb = np.zeros((60, 80, 3), np.float32)
    rgb[:30] = (0.1, 0.2, 0.9)  # blue sky
    rgb[30:] = (0.8, 0.3, 0.1)  # red ground
    rgb[:, 70:] = (0.95, 0.95, 0.95)  # a white strip on the right
    camera = ins.BackgroundCamera(width=80, height=60)
    env = ins.light_from_photo(rgb, camera, width=256).radiance_linear
    from gaffer_envmap.conventions import direction_to_uv
    from gaffer_envmap.sky import sun_direction

    def at(elevation: float, azimuth: float) -> np.ndarray:
        u, v = direction_to_uv(sun_direction(elevation, azimuth))
        return env[int(v * 128), int(u * 256)]

    above, below = at(25.0, 0.0), at(-25.0, 0.0)  # the frame spans +-15 degrees vertically
    assert above[2] > above[0] and below[0] > below[2]
    right, left = at(0.0, 25.0), at(0.0, -25.0)  # and +-19.8 horizontally
    assert right.min() > 2 * left.min()  # the white strip continues to the right, not the left
    np.testing.assert_allclose(at(5.0, 179.0), at(5.0, -179.0), rtol=0.05)  # behind: no seam


def test_a_camera_looking_down_puts_the_horizon_above_the_frame() -> None:
    from gaffer_envmap.poses import look_at_w2c_blender

    level = ins.BackgroundCamera(width=W, height=H)
    assert level.horizon_row == H / 2
    down = ins.BackgroundCamera(
        width=W, height=H, w2c=look_at_w2c_blender(np.array([0.0, -3.0, 3.0]))
    )
    assert down.horizon_row < 0  # 45 degrees down with a 30-degree tall frame
    right, forward = down.ground_axes()
    np.testing.assert_allclose(right, [1.0, 0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(forward, [0.0, 1.0, 0.0], atol=1e-9)


def test_a_background_with_exif_rotation_is_placed_as_displayed(files, tmp_path) -> None:
    """`--at` is checked against the background as shown (EXIF orientation applied, as it is read)."""
    ex = Image.Exif()
    ex[0x0112] = 6  # stored landscape, shown portrait
    Image.open(files["bg"]).convert("RGB").save(tmp_path / "turned.jpg", exif=ex, quality=95)
    out = tmp_path / "t.png"
    argv = ["insert", str(OBJECT), "--into", str(tmp_path / "turned.jpg"), "--out", str(out)]
    assert main([*argv, "--at", "100,180", "--height", "40", "--shadow", "none"]) == 0
    assert _read(out).shape == (W, H, 3)  # 150 wide, 200 tall, as displayed


@pytest.mark.parametrize("kind", ["rgba", "grey16"])
def test_composite_keeps_the_bytes_of_other_kinds_of_background(tmp_path, kind) -> None:
    rng = np.random.default_rng(0)
    if kind == "rgba":
        arr = rng.integers(0, 256, (H, W, 4), dtype=np.uint8)
    else:
        arr = rng.integers(0, 65536, (H, W), dtype=np.uint16)
    Image.fromarray(arr).save(tmp_path / "bg.png")
    background = read_photo(tmp_path / "bg.png")
    placed = _placed()
    shadow = _shadow_for(90.0)
    out = ins.composite(background, placed, shadow)
    assert out.shape == (H, W, 3)
    keep = (shadow == 1.0) & (placed.full_alpha(H, W) == 0)
    assert keep.sum() > 0.6 * H * W
    assert np.array_equal(out[keep], background.rgb_u8[keep])
    assert (out[~keep] != background.rgb_u8[~keep]).any()


def test_sun_at_places_the_key_light_at_the_sun_seen_along_the_camera_heading() -> None:
    pytest.importorskip("astral")
    from datetime import datetime

    from gaffer_diffusion.cli import _parser
    from gaffer_diffusion.cli.insert import SUN_SIZE_DEG, _key_light
    from gaffer_envmap.sun_position import sun_position_at

    when = "2026-06-21T17:00+02:00"
    args = _parser().parse_args(
        ["insert", "o.png", "--into", "b.png", "--out", "x.png", "--sun-at",
         f"48.86,2.29,{when}", "--camera-heading", "180"]
    )  # fmt: skip
    key = _key_light(args)
    sun = sun_position_at(48.86, 2.29, datetime.fromisoformat(when))
    assert key is not None and key.size_deg == SUN_SIZE_DEG
    assert key.azimuth_deg == pytest.approx((sun.azimuth_deg - 180.0) % 360.0)
    assert key.elevation_deg == pytest.approx(sun.elevation_deg)
    # the afternoon sun is in the west: to the right of a camera looking south
    assert 0 < key.azimuth_deg < 180


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--sun-at", "48.86,2.29,2026-06-21T17:00+02:00"], "`--camera-heading"),
        (["--camera-heading", "10"], "`--sun-at"),
        (["--sun-at", "48.86,2.29,2026-06-21T23:00+02:00", "--camera-heading", "0"], "below"),
        (["--sun-at", "48.86,2.29,2026-06-21T17:00", "--camera-heading", "0"], "UTC offset"),
        (["--sun-at", "48.86,2.29,2026-06-21T17:00Z", "--envmap", "city"], "`--sun-at`"),
    ],
)
def test_sun_at_refusals(files, tmp_path, capsys, extra, words) -> None:
    pytest.importorskip("astral")
    assert _run(files, tmp_path / "o.png", *extra) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
    assert list(tmp_path.iterdir()) == []
