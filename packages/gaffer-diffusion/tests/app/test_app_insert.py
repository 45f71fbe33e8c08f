"""The app's "Insert into a photo" tab, in-process, without a browser or a server.

`Engine.insert` must give `gaffer-diffusion insert`'s picture byte for byte on the same inputs and
seed; a click on the background is `--at X,Y`; a click on the lighting panorama is `--key-light
AZ,EL` in the command's convention; the page has the tab and its `/insert` endpoint, whose handler is
called here as Gradio calls it; bad input is one readable message before the model samples.

The background is a perspective view of a bundled HDRI (as tests/test_insert.py), 200 x 150; the
object the shipped example photo; the model the shipped gaffer-tiny (128 px, about a second on a CPU).
"""

import contextlib
import gc
import math
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from gaffer_diffusion import insert as ins
from gaffer_diffusion import pretrained
from gaffer_diffusion.app.config import AppConfig
from gaffer_diffusion.app.engine import Engine
from gaffer_diffusion.app.inserting import (
    KEY_PREVIEW_WH,
    InsertSettings,
    click_to_at,
    key_light_from_click,
    key_light_of,
    key_light_pixel,
    lighting_panorama,
    placement_preview,
    preview_size,
)
from gaffer_diffusion.cli import main
from gaffer_diffusion.errors import InputValueError
from gaffer_diffusion.photo import envmap_backdrop
from gaffer_envmap.bundled import bundled_hdri, read_bundled_hdri
from gaffer_envmap.conventions import direction_to_uv, uv_to_direction

gr = pytest.importorskip(
    "gradio", reason='the app needs its extra: pip install "gaffer-diffusion[app]"'
)

W, H = 200, 150
OBJECT = pretrained.example_dataset_path() / "objects" / "procedural_002" / "lit" / "000_000.png"
MARKER = (255, 40, 200)


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("app-insert")
    env = read_bundled_hdri("courtyard")
    view = envmap_backdrop(env.radiance_linear, ins.LEVEL_CAMERA.rotation, height=H, width=W)
    Image.fromarray(np.round(view * 255).astype(np.uint8)).save(tmp / "bg.png")
    Image.new("L", (10, 10), 255).save(tmp / "small_mask.png")
    return {"bg": tmp / "bg.png", "small_mask": tmp / "small_mask.png"}


@pytest.fixture(scope="module")
def engine() -> Engine:
    return Engine(AppConfig())


@contextlib.contextmanager
def _gradio_loops() -> Iterator[None]:
    """Gradio 6 opens asyncio event loops it never closes while a page is built and components are
    made outside a server; they are collected here, their ResourceWarnings dropped (a server closes
    them at exit; test_app_mp4 builds its page in a subprocess for the same reason)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ResourceWarning)
        try:
            yield
        finally:
            gc.collect()


@pytest.fixture(scope="module")
def page(engine: Engine, tmp_path_factory: pytest.TempPathFactory) -> Any:
    from gaffer_diffusion.app._ui import build_app

    with _gradio_loops():
        return build_app(engine, tmp_path_factory.mktemp("jobs"))


def _handler(page: Any, name: str) -> Any:
    """The function behind an event of the page, as Gradio calls it (its event loops collected)."""
    found = [f.fn for f in page.fns.values() if f.api_name == name]
    assert found, f"no event named {name!r}"

    def call(*args: Any) -> Any:
        with _gradio_loops():
            return found[0](*args)

    return call


def _read(path: str | Path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im.convert("RGB"))


def _cli(files: dict[str, Path], out: Path, *extra: str) -> np.ndarray:
    argv = ["insert", str(OBJECT), "--into", str(files["bg"]), "--out", str(out), *extra]
    assert main([*argv, "--device", "cpu"]) == 0
    return _read(out)


# ----- the engine is the command -----


def test_engine_insert_equals_the_cli_with_a_clicked_key_light(files, engine, tmp_path) -> None:
    """Light from the photo plus a key light placed by a click, placed by a click, seed 3."""
    az, el = key_light_from_click((400, 60))  # right of the middle, up: from the right
    at = click_to_at((120, 130), preview_size((W, H)), (W, H))
    label = engine.model_labels[0]
    settings = InsertSettings(
        at_xy=at, height_px=60.0, key_light=key_light_of(az, el, 3.0, 5.0), seed=3
    )
    outcome = engine.insert(
        label, engine.prepare(label, OBJECT, None), engine.background(files["bg"]), settings
    )
    want = _cli(files, tmp_path / "cli.png", "--at", f"{at[0]},{at[1]}", "--height", "60",
                "--key-light", f"{az},{el},3,5", "--seed", "3")  # fmt: skip
    assert outcome.image.shape == (H, W, 3)
    diff = np.abs(outcome.image.astype(int) - want.astype(int))
    assert diff.max() == 0, f"app and CLI differ by up to {diff.max()} levels"
    # the object stands where clicked: its lowest changed row is the clicked row, centred there
    bg = _read(files["bg"])
    changed = (outcome.image != bg).any(-1)
    assert changed[:, : at[0] - 40].sum() > 50  # a light from the right: the shadow falls left
    assert changed[:, at[0] + 40 :].sum() == 0
    assert outcome.placement.foot_xy == (120.0, 130.0) and outcome.steps == 1
    assert "key light at azimuth" in outcome.lighting and "2d shadow" in outcome.shadow


def test_engine_insert_equals_the_cli_under_a_bundled_map(files, engine, tmp_path) -> None:
    """A chosen map (`--envmap`), the default placement and height, no shadow."""
    label = engine.model_labels[0]
    outcome = engine.insert(
        label,
        engine.prepare(label, OBJECT, None),
        engine.background(files["bg"]),
        InsertSettings(shadow="none"),
        bundled_hdri("courtyard"),
    )
    want = _cli(files, tmp_path / "cli.png", "--envmap", "courtyard", "--shadow", "none")
    assert np.abs(outcome.image.astype(int) - want.astype(int)).max() == 0
    assert "default" in outcome.placement.chosen


# ----- clicks -----


def test_a_click_on_the_placement_preview_is_the_at_pixel() -> None:
    # a background within PLACE_PREVIEW_SIDE is shown as it is: the click is the pixel
    assert preview_size((W, H)) == (W, H)
    assert click_to_at((37, 101), (W, H), (W, H)) == (37, 101)
    # a larger one is shown shrunk: the click maps back to the background pixel under it
    big = (1920, 1280)
    pw, ph = preview_size(big)
    assert (pw, ph) == (768, 512)
    for x, y in [(0, 0), (767, 511), (383, 300), (10, 20)]:
        bx, by = click_to_at((x, y), (pw, ph), big)
        assert 0 <= bx < big[0] and 0 <= by < big[1]
        assert math.floor(bx * pw / big[0]) == x and math.floor(by * ph / big[1]) == y
    # the preview marks the clicked pixel
    rgb = np.full((H, W, 3), 90, np.uint8)
    shown = placement_preview(rgb, (37.0, 101.0), 40.0)
    assert tuple(shown[101, 37]) == MARKER
    assert tuple(shown[101 - 30, 37]) == MARKER  # the height bar, 40 px up from the foot
    assert tuple(shown[101 - 45, 37]) == (90, 90, 90)


@pytest.mark.parametrize("click", [(256, 128), (383, 42), (100, 200), (5, 10), (500, 240)])
def test_a_click_on_the_lighting_is_the_key_light_in_the_cli_convention(click) -> None:
    """The clicked direction is the key light's (`KeyLight.direction`, as `--key-light` makes it),
    and a map built with that key light is brightest under the click."""
    az, el = key_light_from_click(click)
    key = key_light_of(az, el, 3.0, 5.0)
    assert key is not None
    pw, ph = KEY_PREVIEW_WH
    u, v = (click[0] + 0.5) / pw - 0.25, (click[1] + 0.5) / ph  # the Blender map's u is rolled
    np.testing.assert_allclose(
        key.direction, uv_to_direction(np.array(u % 1.0), np.array(v)), atol=1e-3
    )
    x, y = key_light_pixel(az, el)
    assert math.floor(x) % pw == click[0] and math.floor(y) == click[1]
    rgb = np.full((H, W, 3), 0.4, np.float32)
    env = ins.light_from_photo(rgb, ins.BackgroundCamera(width=W, height=H), key)
    peak = np.unravel_index(np.argmax(env.radiance_linear.sum(-1)), env.radiance_linear.shape[:2])
    du, dv = direction_to_uv(key.direction)
    assert abs(peak[0] - float(dv) * env.height) <= 2.5
    assert min(abs(peak[1] - float(du) * env.width) % env.width, env.width - abs(peak[1] - float(du) * env.width) % env.width) <= 2.5 or abs(el) > 80  # fmt: skip


def test_the_lighting_panorama_puts_straight_ahead_in_the_middle() -> None:
    """The middle column is azimuth 0 (world +y, behind the object), the right half the lights from
    the right (+x), as the CLI's help says; the marker sits on the key light."""
    assert key_light_from_click((255, 127))[0] == pytest.approx(0.0, abs=0.5)
    assert key_light_from_click((384, 127))[0] == pytest.approx(90.0, abs=0.5)
    assert abs(key_light_from_click((0, 127))[0]) > 179.0
    key = ins.KeyLight(azimuth_deg=90.0, elevation_deg=0.0)
    np.testing.assert_allclose(key.direction, [1.0, 0.0, 0.0], atol=1e-12)
    env = ins.light_from_photo(
        np.full((H, W, 3), 0.4, np.float32), ins.BackgroundCamera(width=W, height=H)
    )
    key = ins.KeyLight(azimuth_deg=90.0, elevation_deg=30.0)
    shown = lighting_panorama(env, key)
    assert shown.shape == (256, 512, 3)
    x, y = key_light_pixel(90.0, 30.0)
    assert tuple(shown[math.floor(y), math.floor(x)]) == MARKER
    # the picture agrees with the marker: the key light's disc is under it, the photo in the middle
    lit = ins.light_from_photo(
        np.full((H, W, 3), 0.4, np.float32), ins.BackgroundCamera(width=W, height=H), key
    )
    bare = lighting_panorama(lit).sum(-1)
    peak_y, peak_x = np.unravel_index(np.argmax(bare), bare.shape)
    assert abs(peak_x - x) <= 4 and abs(peak_y - y) <= 4, ((peak_x, peak_y), (x, y))
    photo = np.zeros((H, W, 3), np.float32)
    photo[:, W // 2 :] = 1.0  # a photo bright on its right half: bright just right of the middle
    half = lighting_panorama(ins.light_from_photo(photo, ins.BackgroundCamera(width=W, height=H)))
    row = half[128].astype(int).sum(-1)
    assert row[262:280].mean() > row[232:250].mean() + 100


# ----- the page -----


def test_the_page_has_the_insert_tab_and_endpoint(page) -> None:
    tabs = [b.label for b in page.blocks.values() if isinstance(b, gr.Tab)]
    assert tabs == ["Relight", "Insert into a photo"]
    public = {f.api_name for f in page.fns.values() if f.api_visibility == "public"}
    assert {"preview", "auto_mask", "relight", "turntable", "insert"} <= public
    ids = {getattr(b, "elem_id", None) for b in page.blocks.values()}
    for elem in ("insert_place", "insert_key_view", "insert_download", "insert_shadow"):
        assert elem in ids


def _insert_args(files: dict[str, Path], **over: Any) -> list[Any]:
    args = {
        "model": "gaffer-tiny (shipped)",
        "obj": str(OBJECT),
        "mask": None,
        "background": str(files["bg"]),
        "x": 120,
        "y": 130,
        "height": 60,
        "lighting": "photo",
        "words": "",
        "fov": 39.6,
        "az": 90.0,
        "el": 35.0,
        "strength": 3.0,
        "size": 5.0,
        "shadow": "2d",
        "seed": 0,
        "steps": None,
    }
    args.update(over)
    return list(args.values())


def test_the_insert_button_gives_the_full_size_png(page, files, tmp_path) -> None:
    insert = _handler(page, "insert")
    result, mask, download, status = insert(*_insert_args(files))
    got = _read(result)
    assert got.shape == (H, W, 3)
    assert _read(download.value["path"]).tolist() == got.tolist()
    assert np.asarray(Image.open(mask)).shape == (128, 128)  # the object photo's mask
    assert "200x150" in status and "lowest point at 120,130" in status and "shadow" in status
    want = _cli(files, tmp_path / "cli.png", "--at", "120,130", "--height", "60",
                "--key-light", "90,35,3,5")  # fmt: skip
    assert np.abs(got.astype(int) - want.astype(int)).max() == 0
    # shadow off: only the object's own pixels change (its lowest row, 130, antialiased into 131)
    result, _, _, status = insert(*_insert_args(files, shadow="none"))
    bg = _read(files["bg"])
    plain, shadowed = (_read(result) != bg).any(-1), (got != bg).any(-1)
    assert "no shadow" in status and np.nonzero(plain)[0].max() <= 131
    assert (plain <= shadowed).all() and (shadowed & ~plain)[:, :80].sum() > 100  # the shadow, left


def test_clicks_through_the_page(page, files) -> None:
    from gaffer_diffusion.app import _insert_ui

    fns = {f.api_name: _handler(page, f.api_name) for f in page.fns.values()}
    click = gr.SelectData(None, {"index": [57, 99], "value": None})
    x, y, shown = fns["click_placement"](str(files["bg"]), 50, click)
    assert (x, y) == (57, 99) and tuple(shown[99, 57]) == MARKER
    click = gr.SelectData(None, {"index": [384, 64], "value": None})
    az, el, view = fns["click_lighting"](str(files["bg"]), "photo", "", 39.6, 3.0, 5.0, click)
    assert (az, el) == key_light_from_click((384, 64)) and tuple(view[64, 384]) == MARKER
    assert _insert_ui.PHOTO_LIGHT == "photo"


@pytest.mark.parametrize(
    ("over", "match"),
    [
        ({"obj": None}, "Upload a photo of the object"),
        ({"background": None}, "Upload a background photo"),
        ({"y": None}, "both X and Y"),
        ({"x": 500}, r"`--at` 500,130 is outside the background \(200x150\)"),
        ({"height": 400}, r"`--height` 400 does not fit.*pass `--height` \d+ or less"),
        ({"mask": "{small_mask}"}, "10x10"),
        ({"strength": -1.0}, "strength"),
        ({"shadow": "cycles"}, "no Blender shadow"),
        ({"lighting": "source:sky", "words": "  "}, "type the words"),
    ],
)
def test_bad_input_is_one_message_before_the_model_samples(
    page, files, monkeypatch, over, match
) -> None:
    import gaffer_diffusion.insert as library

    def no_sampling(*_a: object, **_k: object) -> None:
        raise AssertionError("the model sampled")

    monkeypatch.setattr(library, "insert_object", no_sampling)
    over = {k: (v.format(**files) if isinstance(v, str) else v) for k, v in over.items()}
    with pytest.raises(gr.Error, match=match) as info:
        _handler(page, "insert")(*_insert_args(files, **over))
    assert "\n" not in info.value.message and "Internal error" not in info.value.message


def test_settings_refuse_what_the_app_does_not_offer() -> None:
    with pytest.raises(InputValueError, match="`steps`"):
        InsertSettings(num_inference_steps=0)
    assert key_light_of(10.0, 20.0, 0.0, 5.0) is None  # strength 0: as insert without --key-light


@pytest.mark.slow
def test_the_insert_endpoint_over_the_wire(app_server: Any, files, tmp_path) -> None:
    """`/insert` through gradio_client against the session's server: the uploads, empty X / Y (the
    default placement) and height 0 (as in its photo) arrive as the CLI's defaults."""
    pytest.importorskip("gradio_client", reason="the app tests drive the app with gradio_client")
    from gradio_client import Client, handle_file

    client = Client(app_server.url, verbose=False, download_files=str(tmp_path / "downloads"))
    args = _insert_args(
        files,
        obj=handle_file(str(OBJECT)),
        background=handle_file(str(files["bg"])),
        x=None,
        y=None,
    )
    args[6] = 0  # height: as in the object photo
    result, _, download, status = client.predict(*args, api_name="/insert")
    want = _cli(files, tmp_path / "cli.png", "--key-light", "90,35,3,5")
    assert np.abs(_read(result).astype(int) - want.astype(int)).max() == 0
    assert _read(download["value"]).tolist() == _read(result).tolist()
    assert "default" in status
