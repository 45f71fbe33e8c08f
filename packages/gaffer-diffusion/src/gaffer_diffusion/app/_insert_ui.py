"""The page's "Insert into a photo" tab: widgets wired to `Engine.insert`.

Upload an object and a background, click the background where the object stands, click the lighting
panorama where the key light is (or move its sliders), choose the shadow, insert, download. What each
control means is `gaffer-diffusion insert`'s flag of the same name (`app.inserting`).

Import this module only after `server.py` has set Gradio's environment (as `_ui.py`).
"""

import functools
import html
from pathlib import Path
from typing import Any

import gradio as gr
import numpy as np

from gaffer_diffusion._choices import BACKDROP_FOV_DEG
from gaffer_diffusion.app._page import OUTPUT_BUTTONS, Jobs, save_png, shown_in_page
from gaffer_diffusion.app.engine import AUTO_MASK_NOTE, Engine
from gaffer_diffusion.app.inserting import (
    INSERT_SHADOWS,
    InsertSettings,
    click_to_at,
    key_light_from_click,
    key_light_of,
    lighting_panorama,
    placement_preview,
    preview_size,
)
from gaffer_diffusion.insert_geometry import KEY_SIZE_DEG, KEY_STRENGTH, default_placement
from gaffer_diffusion.photo import Photo

PHOTO_LIGHT = "photo"
"""The lighting choice `insert --light-from-photo`: the background wrapped onto the sphere + the key light."""

KEY_DEFAULT = (-135.0, 45.0)
"""The key light's azimuth and elevation when the tab opens: from behind the camera, on its left, high."""

Num = float | int
"""What a Gradio number or slider gives: an int with `precision=0` or a whole step, else a float."""

_shown = shown_in_page("Cannot insert")


@functools.lru_cache(maxsize=2)
def _read_background(engine: Engine, path: str) -> Photo:
    """The background, read once per upload (Gradio names an upload's folder by its content hash)."""
    return engine.background(path)


def _at(x: Num | None, y: Num | None) -> tuple[float, float] | None:
    """`--at` of the X and Y fields: both, or neither (the default placement)."""
    if x is None and y is None:
        return None
    if x is None or y is None:
        raise gr.Error(
            "Give both X and Y of the placement (click the background preview), or clear both for "
            "the default (the centre of the bottom third).",
            title="Cannot insert",
            print_exception=False,
        )
    return float(x), float(y)


def build_insert_tab(
    engine: Engine,
    jobs: Jobs,
    model: gr.Dropdown,
    *,
    hdris: list[str],
    text_sources: list[str],
    source_maps: Path,
) -> None:
    """The tab's widgets and events, inside the current `gr.Tab`; API endpoint `/insert`.

    Args:
        engine: the app's engine.
        jobs: the page's output folders.
        model: the page's model picker (shared with the relight tab).
        hdris: the bundled HDRIs offered as lighting.
        text_sources: the lighting sources that start from words.
        source_maps: where maps made from words are kept.
    """
    from gaffer_envmap.bundled import bundled_hdri

    def _envmap(lighting: str | None, words: str | None) -> str | None:
        """The chosen map's path, or None for the lighting from the photo."""
        choice = lighting or PHOTO_LIGHT
        if choice == PHOTO_LIGHT:
            return None
        kind, _, name = choice.partition(":")
        if kind == "hdri":
            return str(bundled_hdri(name))
        return str(engine.source_envmap_path(name, words or "", source_maps))

    @_shown
    def show_placement(
        background: str | None, x: Num | None, y: Num | None, height: Num | None
    ) -> Any:
        if not background:
            return None
        photo = _read_background(engine, background)
        w, h = photo.size_wh
        at = _at(x, y)
        if at is None:
            at = default_placement(w, h, 0).foot_xy
        return placement_preview(photo.rgb_u8, at, float(height) if height else None)

    @_shown
    def click_placement(
        background: str | None, height: Num | None, evt: gr.SelectData
    ) -> tuple[Any, ...]:
        if not background:
            return gr.skip(), gr.skip(), gr.skip()
        photo = _read_background(engine, background)
        wh = photo.size_wh
        x, y = click_to_at(evt.index, preview_size(wh), wh)
        return x, y, placement_preview(photo.rgb_u8, (x, y), float(height) if height else None)

    def _panorama(
        background: str | None,
        lighting: str | None,
        words: str | None,
        fov: Num,
        key: tuple[Num, Num, Num, Num],
    ) -> np.ndarray | None:
        path = _envmap(lighting, words)
        if path is not None:
            return lighting_panorama(engine.envmap(path))
        if not background:
            return None
        photo = _read_background(engine, background)
        settings = InsertSettings(fov_deg=float(fov), key_light=key_light_of(*key))
        env = engine.insert_lighting(photo, settings).envmap
        return lighting_panorama(env, settings.key_light)

    @_shown
    def show_lighting(
        background: str | None,
        lighting: str | None,
        words: str | None,
        fov: Num,
        az: Num,
        el: Num,
        strength: Num,
        size: Num,
    ) -> Any:
        return _panorama(background, lighting, words, fov, (az, el, strength, size))

    @_shown
    def click_lighting(
        background: str | None,
        lighting: str | None,
        words: str | None,
        fov: Num,
        strength: Num,
        size: Num,
        evt: gr.SelectData,
    ) -> tuple[Any, ...]:
        az, el = key_light_from_click(evt.index)
        return az, el, _panorama(background, lighting, words, fov, (az, el, strength, size))

    @_shown
    def insert(
        model: str,
        obj: str | None,
        mask: str | None,
        background: str | None,
        x: Num | None,
        y: Num | None,
        height: Num | None,
        lighting: str | None,
        words: str | None,
        fov: Num,
        az: Num,
        el: Num,
        strength: Num,
        size: Num,
        shadow: str,
        seed: Num | None,
        steps: Num | None,
    ) -> tuple[Any, ...]:
        if not obj:
            raise gr.Error(
                "Upload a photo of the object first (RGBA, or RGB: its mask is estimated).",
                title="Cannot insert",
                print_exception=False,
            )
        if not background:
            raise gr.Error(
                "Upload a background photo to insert the object into.",
                title="Cannot insert",
                print_exception=False,
            )
        if shadow not in INSERT_SHADOWS:
            raise gr.Error(
                f"Shadow {html.escape(str(shadow), quote=False)!r}: choose one of "
                f"{', '.join(INSERT_SHADOWS)} (the app has no Blender shadow yet).",
                title="Cannot insert",
                print_exception=False,
            )
        envmap = _envmap(lighting, words)
        settings = InsertSettings(
            at_xy=_at(x, y),
            height_px=float(height) if height else None,
            fov_deg=float(fov),
            key_light=key_light_of(az, el, strength, size) if envmap is None else None,
            shadow=shadow,  # type: ignore[arg-type]  # InsertSettings refuses other values
            seed=0 if seed is None else int(seed),
            num_inference_steps=None if steps in (None, 0) else int(steps),  # type: ignore[arg-type]
        )
        photo = _read_background(engine, background)
        prepared = engine.prepare(model, obj, mask or None)
        outcome = engine.insert(model, prepared, photo, settings, envmap)
        out = jobs.new()
        path = save_png(out / "inserted.png", outcome.image)
        w, h = photo.size_wh
        p = outcome.placement
        notes = [
            f"Inserted with {outcome.model} ({outcome.steps} step(s)) in {outcome.seconds:.1f} s, "
            f"at the background's size, {w}x{h} px",
            f"the object {p.height_px:g} px tall, its lowest point at {p.foot_xy[0]:g},"
            f"{p.foot_xy[1]:g}" + (f" ({p.chosen})" if p.chosen else ""),
            f"lighting: {outcome.lighting}"
            + ("; the key light goes with the lighting from the photo" if envmap else ""),
            f"shadow: {outcome.shadow}",
        ]
        status = "; ".join(notes) + "." + (f" {AUTO_MASK_NOTE}" if prepared.auto_mask else "")
        return (
            path,
            save_png(out / "mask.png", outcome.mask),
            gr.DownloadButton(value=path, interactive=True),
            status,
        )

    gr.Markdown(
        "Upload an object (an RGBA PNG, or an RGB photo: its mask is estimated) and a background "
        "photo. **Click the background** where the object stands (its lowest centre point), **click "
        "the lighting panorama** where the key light is (or move its sliders), choose the shadow and "
        "insert: the object is relit under the background's light, placed, shadowed and composited "
        "at the background's full size (`gaffer-diffusion insert`)."
    )
    with gr.Row():
        with gr.Column(scale=1):
            obj = gr.Image(
                label="Object (RGBA, or RGB: its mask is estimated)",
                type="filepath",
                image_mode=None,
                sources=["upload", "clipboard"],
                elem_id="insert_object",
                height=200,
            )
            mask = gr.Image(
                label="Object mask (optional, white = object; replaces the alpha or GrabCut's)",
                type="filepath",
                image_mode=None,
                sources=["upload"],
                elem_id="insert_mask",
                height=120,
            )
            background = gr.Image(
                label="Background photo",
                type="filepath",
                image_mode=None,
                sources=["upload", "clipboard"],
                elem_id="insert_background",
                height=200,
            )
        with gr.Column(scale=2):
            place = gr.Image(
                label="Click where the object stands (its lowest centre point)",
                interactive=False,
                format="png",
                elem_id="insert_place",
                height=360,
            )
            with gr.Row():
                at_x = gr.Number(value=None, precision=0, label="X (--at)", elem_id="insert_x")
                at_y = gr.Number(value=None, precision=0, label="Y (--at)", elem_id="insert_y")
                height = gr.Slider(
                    0,
                    engine.config.max_image_side,
                    value=0,
                    step=1,
                    label="Object height, px (--height; 0: as in its photo)",
                    elem_id="insert_height",
                )
    with gr.Row():
        with gr.Column(scale=1):
            lighting = gr.Dropdown(
                choices=[
                    ("the background photo + the key light (--light-from-photo)", PHOTO_LIGHT),
                    *((f"bundled HDRI: {n}", f"hdri:{n}") for n in hdris),
                    *((f"words: {n} (type them below)", f"source:{n}") for n in text_sources),
                ],
                value=PHOTO_LIGHT,
                label="Lighting",
                elem_id="insert_lighting",
            )
            words = gr.Textbox(
                label="Words, for a words lighting (press Enter)",
                placeholder="golden hour from the left",
                elem_id="insert_words",
            )
            fov = gr.Slider(
                5,
                150,
                value=BACKDROP_FOV_DEG,
                step=0.1,
                label="Background's horizontal field of view, deg (--fov)",
                elem_id="insert_fov",
            )
            shadow = gr.Radio(
                choices=[("2d: a soft pixel-height shadow", "2d"), ("none", "none")],
                value="2d",
                label="Shadow (--shadow)",
                elem_id="insert_shadow",
            )
        with gr.Column(scale=2):
            key_view = gr.Image(
                label="Lighting: click to put the key light (middle: straight ahead, behind the "
                "object; right: from the right; edges: behind the camera)",
                interactive=False,
                format="png",
                elem_id="insert_key_view",
                height=256,
            )
            with gr.Row():
                key_az = gr.Slider(
                    -180,
                    180,
                    value=KEY_DEFAULT[0],
                    step=0.01,
                    label="Key light azimuth, deg (90: from the right; +-180: behind the camera)",
                    elem_id="insert_key_azimuth",
                )
                key_el = gr.Slider(
                    -90,
                    90,
                    value=KEY_DEFAULT[1],
                    step=0.01,
                    label="Key light elevation, deg",
                    elem_id="insert_key_elevation",
                )
            with gr.Row():
                key_strength = gr.Slider(
                    0,
                    20,
                    value=KEY_STRENGTH,
                    step=0.1,
                    label="Key light strength (x the photo's mean light; 0: no key light)",
                    elem_id="insert_key_strength",
                )
                key_size = gr.Slider(
                    0.5,
                    90,
                    value=KEY_SIZE_DEG,
                    step=0.5,
                    label="Key light size, deg",
                    elem_id="insert_key_size",
                )
    with gr.Accordion("Sampling", open=False):
        with gr.Row():
            steps = gr.Number(
                value=None,
                precision=0,
                label="Steps (empty: the model's suggestion)",
                elem_id="insert_steps",
            )
            seed = gr.Number(value=0, precision=0, label="Seed", elem_id="insert_seed")
    insert_btn = gr.Button("Insert", variant="primary", elem_id="insert")
    status = gr.Markdown(elem_id="insert_status")
    with gr.Row():
        result = gr.Image(
            label="Inserted (the background's full size)",
            interactive=False,
            buttons=OUTPUT_BUTTONS,
            type="filepath",
            elem_id="insert_result",
            height=360,
        )
        used_mask = gr.Image(
            label="Object mask used",
            interactive=False,
            buttons=OUTPUT_BUTTONS,
            type="filepath",
            elem_id="insert_mask_used",
            height=360,
        )
    download = gr.DownloadButton(
        "Download the PNG (full size)", interactive=False, elem_id="insert_download"
    )

    private: dict[str, Any] = {"api_visibility": "private", "show_progress": "hidden"}
    placement_inputs = [background, at_x, at_y, height]
    background.change(show_placement, placement_inputs, place, **private)
    # .input: typed into the box or dragged (the last value drawn); not the click's own updates
    for field in (at_x, at_y, height):
        field.input(show_placement, placement_inputs, place, trigger_mode="always_last", **private)
    place.select(click_placement, [background, height], [at_x, at_y, place], **private)
    key_inputs = [background, lighting, words, fov, key_az, key_el, key_strength, key_size]
    for slider in (key_az, key_el, key_strength, key_size, fov):
        slider.input(show_lighting, key_inputs, key_view, trigger_mode="always_last", **private)
    background.change(show_lighting, key_inputs, key_view, **private)
    lighting.change(show_lighting, key_inputs, key_view, **private)
    words.submit(show_lighting, key_inputs, key_view, **private)
    key_view.select(
        click_lighting,
        [background, lighting, words, fov, key_strength, key_size],
        [key_az, key_el, key_view],
        **private,
    )
    placing = [model, obj, mask, background, at_x, at_y, height, lighting, words, fov]
    insert_btn.click(
        insert,
        [*placing, key_az, key_el, key_strength, key_size, shadow, seed, steps],
        [result, used_mask, download, status],
        api_name="insert",
        concurrency_id="model",
        concurrency_limit=1,
    )
