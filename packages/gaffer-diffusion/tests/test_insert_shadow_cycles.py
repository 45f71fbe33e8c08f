"""`--shadow cycles`: Cycles' shadow catcher under the insert's map, from a proxy
built from the placed mask and the estimated normals, rendered in a Blender worker process.

The proxy's geometry is checked without bpy; the renders (a few seconds each at a small size) are
skipped where bpy is not installed."""

import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from gaffer_diffusion import insert as ins
from gaffer_diffusion import insert_shadow_cycles as cyc
from gaffer_diffusion import pretrained
from gaffer_diffusion.cli import main
from gaffer_diffusion.errors import ConfigError, MissingDependencyError
from gaffer_diffusion.photo import Photo, RelitObject, envmap_backdrop, object_alpha, read_photo
from gaffer_envmap.bundled import read_bundled_hdri
from gaffer_envmap.environment_map import EnvironmentMap

W, H = 240, 180
OBJECT = pretrained.example_dataset_path() / "objects" / "procedural_002" / "lit" / "000_000.png"
needs_bpy = pytest.mark.skipif(not cyc.bpy_available(), reason="bpy (gaffer-data[render]) absent")
SMALL = cyc.CyclesShadowConfig(size=96, samples=16, threads=1)


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> dict:
    tmp = tmp_path_factory.mktemp("cycles")
    env = read_bundled_hdri("courtyard")
    view = envmap_backdrop(env.radiance_linear, ins.LEVEL_CAMERA.rotation, height=H, width=W)
    Image.fromarray(np.round(view * 255).astype(np.uint8)).save(tmp / "bg.png")
    photo = read_photo(OBJECT)
    alpha = object_alpha(photo, None)
    h, w = alpha.shape
    relit = RelitObject(box=(0, 0, h, w), rgb=photo.rgb, alpha=alpha)
    extent = ins.object_extent(alpha)
    placement = ins.resolve_placement((W, H), extent, at_xy=(120, 150), height_px=60)
    placed = ins.place_object(relit, extent, placement, (H, W))
    return {"bg": tmp / "bg.png", "placed": placed, "background": read_photo(tmp / "bg.png")}


def _lighting(background: Photo, azimuth: float) -> ins.InsertLighting:
    camera = ins.BackgroundCamera(width=W, height=H)
    key = ins.KeyLight(azimuth_deg=azimuth, elevation_deg=35.0, strength=4.0)
    env = ins.light_from_photo(background.rgb, camera, key)
    return ins.InsertLighting(envmap=env, camera=camera, key_light=key)


def _project(camera: ins.BackgroundCamera, c2w: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Background pixel-edge coordinates `[N, 2]` of world points seen by the Blender camera."""
    rel = (pts - c2w[:3, 3]) @ c2w[:3, :3]  # camera frame: x right, y up, -z forward
    f = camera.focal_px
    return np.stack(
        [
            camera.width / 2 + f * rel[:, 0] / -rel[:, 2],
            camera.height / 2 - f * rel[:, 1] / -rel[:, 2],
        ],
        1,
    )


def test_the_proxy_stands_on_the_ground_at_the_foot_and_covers_the_mask(scene) -> None:
    placed = scene["placed"]
    camera = ins.BackgroundCamera(width=W, height=H)
    proxy = cyc.proxy_scene(placed, camera)
    v = proxy.proxy_verts
    assert math.isclose(proxy.foot_world[2], 0.0, abs_tol=1e-9)  # camera 1 above the ground at z 0
    assert v[:, 2].min() >= -1e-9 and math.isclose(
        v[:, 2].max(), placed.height_px * proxy.units_per_px, rel_tol=0.05
    )
    # seen from the camera, the front of the proxy lies on the placed object's box, and fills it
    uv = _project(camera, proxy.c2w, v)
    ys, xs = np.nonzero(placed.alpha > 0.5)
    t, l = placed.box[0] + ys.min(), placed.box[1] + xs.min()
    b, r = placed.box[0] + ys.max() + 1, placed.box[1] + xs.max() + 1
    m = 0.15 * (b - t)  # the front stands nearer than the foot's plane, so it looks a bit larger
    assert uv[:, 0].min() >= l - m and uv[:, 0].max() <= r + m
    assert uv[:, 1].min() >= t - m and uv[:, 1].max() <= b + m
    assert uv[:, 0].max() - uv[:, 0].min() > 0.8 * (r - l)
    # every face is a quad of existing vertices; the solid is as deep as it is wide (round runs)
    assert proxy.proxy_faces.max() < len(v) and proxy.proxy_faces.shape[1] == 4
    _, forward = camera.ground_axes()
    depth = (v - proxy.foot_world) @ forward
    width = (r - l) * proxy.units_per_px
    assert 0.5 * width < np.ptp(depth) < 1.5 * width


def test_a_relief_reshapes_the_front_and_the_lowest_row_meets_the_foot(scene) -> None:
    placed = scene["placed"]
    camera = ins.BackgroundCamera(width=W, height=H)
    _, forward = camera.ground_axes()
    round_ = cyc.proxy_scene(placed, camera)
    inside = (placed.alpha > 0.5).astype(np.float64)
    ramp = np.broadcast_to(np.linspace(0, 20, placed.alpha.shape[1]), placed.alpha.shape) * inside
    tilted = cyc.proxy_scene(placed, camera, ramp)
    assert not np.allclose(round_.proxy_verts, tilted.proxy_verts)
    for proxy in (round_, tilted):
        v = proxy.proxy_verts
        depth = (v - proxy.foot_world) @ forward  # along the ground, away from the camera
        low = v[:, 2] <= v[:, 2].min() + 1e-9  # the lowest row's vertices
        # its nearest point is at the foot's depth (the object's visible surface meets the ground
        # there); nothing of the proxy stands nearer than the foot by more than the object is tall
        assert math.isclose(depth[low].min(), 0.0, abs_tol=1e-6)
        assert depth.min() > -placed.height_px * proxy.units_per_px
    # a flat relief of h pixels: a slab 2h deep (the back mirrors the front)
    slab = cyc.proxy_scene(placed, camera, 5.0 * inside)
    depth = (slab.proxy_verts - slab.foot_world) @ forward
    assert math.isclose(np.ptp(depth), 10.0 * slab.units_per_px, rel_tol=1e-6)


def test_a_relief_off_the_grid_or_not_finite_is_refused(scene) -> None:
    placed = scene["placed"]
    camera = ins.BackgroundCamera(width=W, height=H)
    with pytest.raises(ConfigError, match="placed object's grid"):
        cyc.proxy_scene(placed, camera, np.zeros((3, 3)))
    bad = np.zeros(placed.alpha.shape)
    bad[0, 0] = np.nan
    with pytest.raises(ConfigError, match="finite"):
        cyc.proxy_scene(placed, camera, bad)


def test_the_proxy_albedo_is_the_object_colour_over_the_mean_radiance() -> None:
    alpha = np.ones((4, 4), np.float32)
    grey = np.full((4, 4, 3), 0.5, np.float32)  # sRGB 0.5: linear 0.214
    placed = ins.PlacedObject(
        box=(0, 0, 4, 4), rgb=grey, alpha=alpha, foot_edge=(2.0, 4.0), height_px=4.0
    )
    env = EnvironmentMap(radiance_linear=np.full((16, 32, 3), 0.5, np.float32))
    assert np.allclose(cyc.proxy_albedo(placed, env), 0.214 / 0.5, atol=2e-3)
    dim = EnvironmentMap(radiance_linear=np.full((16, 32, 3), 0.01, np.float32))
    assert cyc.proxy_albedo(placed, dim) == (cyc.MAX_ALBEDO,) * 3  # never brighter than real


def test_without_bpy_cycles_is_refused_naming_the_fallback(monkeypatch) -> None:
    monkeypatch.setattr(cyc, "bpy_available", lambda: False)
    with pytest.raises(ImportError, match=r"`--shadow 2d`"):
        cyc.require_bpy()


@needs_bpy
def test_the_cycles_shadow_falls_away_from_the_key_light(scene) -> None:
    """Light from the right (azimuth 90): the ground left of the foot darkens, the right does not;
    from the left (270) the other way round; pixels far away keep their bytes."""
    placed, background = scene["placed"], scene["background"]
    fy = placed.foot_edge[1]
    cols = np.nonzero((placed.alpha > 0.5).any(0))[0] + placed.box[1]  # the mask's columns
    rows = slice(int(fy) - 4, int(fy) + 2)
    left = slice(int(cols.min()) - 30, int(cols.min()) - 2)
    right = slice(int(cols.max()) + 3, int(cols.max()) + 31)
    sides = {}
    for azimuth in (90.0, 270.0):
        lighting = _lighting(background, azimuth)
        light = ins.dominant_light(lighting.envmap, lighting.key_light)
        shadow = cyc.cast_shadow_cycles(placed, lighting, light, SMALL)
        f = shadow.factor
        assert f.shape == (H, W) and f.dtype == np.float32 and 0 < f.min() and f.max() == 1.0
        assert max(shadow.render_wh) <= SMALL.size + 1 and shadow.seconds > 0
        sides[azimuth] = float(f[rows, left].mean()), float(f[rows, right].mean())
        # far from the object and its shadow: untouched, and the composite keeps the bytes there
        t, l, b, _ = shadow.region
        assert (f[:t] == 1).all() and (f[b:] == 1).all() and (f[:, :l] == 1).all()
        out = ins.composite(background, placed, f)
        keep = (f == 1.0) & (placed.full_alpha(H, W) == 0)
        assert keep[: max(t, 1)].all() and np.array_equal(out[keep], background.rgb_u8[keep])
        dark = (f < 0.9) & (placed.full_alpha(H, W) == 0)  # the shadow beside the object
        assert dark.sum() > 50 and (out[dark] < background.rgb_u8[dark]).all(1).mean() > 0.9
    (l90, r90), (l270, r270) = sides[90.0], sides[270.0]
    assert l90 < r90 - 0.05 and r270 < l270 - 0.05, sides


def _run(scene, out: Path, *extra: str) -> int:
    return main(
        [
            *("insert", str(OBJECT), "--into", str(scene["bg"]), "--out", str(out)),
            *("--at", "120,150", "--height", "60", "--key-light", "90,35", *extra),
        ]
    )


@needs_bpy
def test_cli_cycles_writes_the_whole_picture_or_nothing(scene, tmp_path, monkeypatch, capsys):
    out = tmp_path / "o.png"
    assert _run(scene, out, "--shadow", "cycles") == 0
    said = capsys.readouterr().out
    assert "shadow: cycles" in said and out.is_file()
    assert "a proxy from the mask and the normals estimated by gaffer-normals" in said
    got = np.asarray(Image.open(out).convert("RGB"))
    bg = scene["background"].rgb_u8
    assert got.shape == bg.shape and (got[:40] == bg[:40]).all()  # far above: the bytes
    assert (got != bg).any(-1).sum() > 200
    # a failing Blender worker: one line naming the fallback, and no picture
    monkeypatch.setattr(cyc, "WORKER", "gaffer_diffusion._no_such_worker")
    failed = tmp_path / "f.png"
    assert _run(scene, failed, "--shadow", "cycles") == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]  # after the weights' progress bars
    assert "Blender worker failed" in err and "`--shadow 2d`" in err and not failed.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.png"]


def test_estimated_proxy_without_estimator_weights_is_refused_before_sampling(monkeypatch) -> None:
    """`proxy="estimated"` names the missing file and `proxy='mask'`; "auto" falls back, "mask"
    does not look; other shadows need neither."""
    monkeypatch.setattr(cyc, "bpy_available", lambda: True)
    monkeypatch.setattr(ins, "_estimator_missing", lambda: "/x/gaffer_normals.json is missing")
    config = ins.InsertConfig(shadow="cycles", proxy="estimated")
    with pytest.raises(
        MissingDependencyError, match=r"gaffer_normals\.json is missing.*proxy='mask'"
    ):
        ins.check_shadow(config)
    auto = ins.check_shadow(ins.InsertConfig(shadow="cycles"))
    assert auto == "/x/gaffer_normals.json is missing"
    assert ins.check_shadow(ins.InsertConfig(shadow="cycles", proxy="mask")) is None
    assert ins.check_shadow(ins.InsertConfig(shadow="2d", proxy="estimated")) is None
    monkeypatch.setattr(cyc, "bpy_available", lambda: False)
    with pytest.raises(MissingDependencyError, match=r"`--shadow 2d`"):
        ins.check_shadow(ins.InsertConfig(shadow="cycles", proxy="mask"))


@needs_bpy
def test_cli_cycles_falls_back_to_the_mask_proxy_and_says_so(scene, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(ins, "_estimator_missing", lambda: "/x/gaffer_normals.json is missing")
    assert _run(scene, tmp_path / "o.png", "--shadow", "cycles") == 0
    said = capsys.readouterr().out
    assert "a proxy inflated from the mask (no estimated normals: /x/gaffer_normals.json" in said
