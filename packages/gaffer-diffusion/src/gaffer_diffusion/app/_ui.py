"""The Gradio page of `gaffer-diffusion app`: widgets wired to `Engine` calls, nothing else.

Import this module only after `server.py` has set Gradio's environment (analytics off, cache folder):
Gradio reads both when it is imported.
"""

import logging
import time
from pathlib import Path
from typing import Any

import gradio as gr

from gaffer_diffusion.app._insert_ui import build_insert_tab
from gaffer_diffusion.app._page import (
    ENVMAP_SUFFIXES,
    OUTPUT_BUTTONS,
    Jobs,
    digest,
    envmap_path,
    save_png,
    shown_in_page,
)
from gaffer_diffusion.app.engine import (
    AUTO_MASK_NOTE,
    MP4_UNAVAILABLE,
    OUTPUT_SIZES,
    CameraPose,
    Engine,
    PhotoInput,
    RelightResult,
    mp4_backend,
    write_gif,
    write_mp4,
)

logger = logging.getLogger(__name__)

DEFAULT_HDRI = "sunrise"
"""The bundled map selected when the page opens (the shipped example's input lighting)."""

_shown_in_page = shown_in_page("Cannot relight")


def build_app(engine: Engine, jobs_root: Path) -> gr.Blocks:
    """The page: the model picker, then two tabs. "Relight": inputs (photo, mask, lighting), live
    lighting previews, relight, turntable. "Insert into a photo": `_insert_ui.build_insert_tab`.

    API endpoints (for `gradio_client`): `/preview`, `/auto_mask`, `/relight`, `/turntable`, `/insert`.
    """
    from gaffer_envmap.bundled import bundled_hdris

    jobs = Jobs(jobs_root)
    source_maps = jobs_root / "source-maps"  # maps made by lighting sources from words
    text_sources = engine.text_sources()
    hdris = list(bundled_hdris())
    labels = engine.model_labels
    mp4 = (
        mp4_backend()
    )  # probed once: the MP4 button is hidden, with the reason, without an encoder

    def _lighting_path(
        hdri: str | None, envfile: str | None, source: str | None, words: str | None
    ) -> str:
        """A lighting source's map of the words when one is chosen, else the upload or the HDRI."""
        if source:
            return str(engine.source_envmap_path(source, words or "", source_maps))
        return envmap_path(hdri, envfile)

    @_shown_in_page
    def preview(
        model: str,
        hdri: str,
        envfile: str | None,
        az: float,
        el: float,
        spin: float,
        source: str | None = None,
        words: str | None = None,
    ) -> tuple[Any, ...]:
        shown = engine.preview(
            model,
            _lighting_path(hdri, envfile, source, words),
            CameraPose(azimuth_deg=float(az), elevation_deg=float(el), spin_deg=float(spin)),
        )
        return shown.ldr, shown.hdr, shown.camera_view

    def _run(
        model: str,
        photo: str | None,
        mask: str | None,
        hdri: str,
        envfile: str | None,
        pose: tuple[float, float, float],
        steps: float | None,
        seed: float | None,
        output_size: str | None,
        frames: int,
        words_light: tuple[str | None, str | None] = ("", ""),
    ) -> tuple[PhotoInput, RelightResult, Path, float]:
        if not photo:
            raise gr.Error(
                "Upload a photo of the object first (RGBA, or RGB with a mask or the automatic one).",
                print_exception=False,
            )
        size = output_size or "photo"
        if size not in OUTPUT_SIZES:
            raise gr.Error(
                f"Output size must be one of {', '.join(OUTPUT_SIZES)}.", print_exception=False
            )
        t0 = time.perf_counter()
        cap = engine.config.max_turntable_side if frames > 1 and size == "photo" else None
        prepared = engine.prepare(model, photo, mask or None, max_side=cap)
        result = engine.relight(
            model,
            prepared,
            _lighting_path(hdri, envfile, *words_light),
            CameraPose(
                azimuth_deg=float(pose[0]), elevation_deg=float(pose[1]), spin_deg=float(pose[2])
            ),
            num_inference_steps=None if steps in (None, 0) else int(steps),
            seed=0 if seed is None else int(seed),
            frames=frames,
            output_size=size,  # type: ignore[arg-type]
        )
        return prepared, result, jobs.new(), time.perf_counter() - t0

    def _size_text(prepared: PhotoInput, result: RelightResult) -> str:
        h, w = result.frames[0].shape[:2]
        if result.output_size == "model":
            return f"the model's {w}x{h} px object crop"
        text = f"the photo's size, {w}x{h} px, with detail transfer"
        if prepared.shrunk_from is not None:
            pw, ph = prepared.shrunk_from
            text = (
                f"{w}x{h} px, the {pw}x{ph} photo shrunk to `--max-turntable-side` "
                f"{engine.config.max_turntable_side}, with detail transfer"
            )
        return text

    def _mask_text(prepared: PhotoInput, mask: str | None, auto_digest: str) -> str:
        # the automatic mask: computed here (no mask), or the one put in the mask field, unchanged
        shown_auto = bool(mask) and bool(auto_digest) and digest(mask) == auto_digest
        return f" {AUTO_MASK_NOTE}" if prepared.auto_mask or shown_auto else ""

    @_shown_in_page
    def auto_mask(photo: str | None, mask: str | None, auto_digest: str) -> tuple[Any, ...]:
        """A new photo without alpha gets GrabCut's mask in the mask field (a user's upload stays).

        The session remembers the automatic mask's SHA-256, so that it is told from a user's mask.
        """
        if not photo or engine.has_alpha(photo):
            return (None if auto_digest else gr.skip()), "", ""
        if mask and not auto_digest:
            return gr.skip(), "", ""
        out = jobs.new()
        path = save_png(out / "auto_mask.png", engine.auto_mask(photo))
        return path, digest(path), AUTO_MASK_NOTE

    @_shown_in_page
    def relight(
        model: str,
        photo: str | None,
        mask: str | None,
        hdri: str,
        envfile: str | None,
        az: float,
        el: float,
        spin: float,
        steps: float | None,
        seed: float | None,
        output_size: str | None = "photo",
        auto_digest: str = "",
        source: str | None = None,
        words: str | None = None,
    ) -> tuple[Any, ...]:
        prepared, result, out, seconds = _run(
            model,
            photo,
            mask,
            hdri,
            envfile,
            (az, el, spin),
            steps,
            seed,
            output_size,
            0,
            (source, words),
        )
        relit = save_png(out / "relit.png", result.frames[0])
        status = (
            f"Relit with {result.model} ({result.steps} step(s)) in {seconds:.1f} s, at "
            f"{_size_text(prepared, result)}.{_mask_text(prepared, mask, auto_digest)}"
        )
        return (
            save_png(out / "input.png", result.input_rgb),
            # the mask beside the output: the photo's at full size, the crop's with the crop
            save_png(
                out / "mask.png", result.mask if result.output_size == "model" else prepared.mask
            ),
            relit,
            gr.DownloadButton(value=relit, interactive=True),
            status,
        )

    @_shown_in_page
    def turntable(
        model: str,
        photo: str | None,
        mask: str | None,
        hdri: str,
        envfile: str | None,
        az: float,
        el: float,
        spin: float,
        steps: float | None,
        seed: float | None,
        output_size: str | None,
        frames: float,
        fps: float,
        auto_digest: str = "",
        source: str | None = None,
        words: str | None = None,
    ) -> tuple[Any, ...]:
        n = int(frames)
        if n < 2:
            raise gr.Error("A turntable needs 2 or more frames.", print_exception=False)
        prepared, result, out, seconds = _run(
            model,
            photo,
            mask,
            hdri,
            envfile,
            (az, el, spin),
            steps,
            seed,
            output_size,
            n,
            (source, words),
        )
        gif = str(write_gif(out / "turntable.gif", result.frames, float(fps)))
        status = (
            f"Turntable of {n} frames with {result.model} in {seconds:.1f} s, at "
            f"{_size_text(prepared, result)}.{_mask_text(prepared, mask, auto_digest)}"
        )
        mp4_button: Any = gr.skip()
        if mp4 is not None:
            video = str(write_mp4(out / "turntable.mp4", result.frames, float(fps)))
            mp4_button = gr.DownloadButton(value=video, interactive=True)
        return gif, gr.DownloadButton(value=gif, interactive=True), mp4_button, status

    with gr.Blocks(
        title="gaffer: relight an object", analytics_enabled=False, delete_cache=(600, 3600)
    ) as demo:
        gr.Markdown(
            "# gaffer: relight an object from one photo, or insert it into another\n"
            "**Relight**: upload a photo of an object (an RGBA PNG with a transparent background, or an "
            "RGB photo: its mask is estimated and shown, and you can upload a better one in its "
            "place), choose the lighting, and relight it at the photo's full size. **Insert into a "
            "photo**: place it in a background photo, lit by that photo, with a shadow. Everything "
            "runs on this machine."
        )
        model = gr.Dropdown(choices=labels, value=labels[0], label="Model", elem_id="model")
        with gr.Tabs():
            with gr.Tab("Relight", id="relight_tab", elem_id="relight_tab"):
                with gr.Row():
                    with gr.Column():
                        photo = gr.Image(
                            label="Photo (RGBA, or RGB: its mask is estimated below)",
                            type="filepath",
                            image_mode=None,
                            sources=["upload", "clipboard"],
                            elem_id="photo",
                            height=260,
                        )
                        mask = gr.Image(
                            label="Mask (white = object) for photos without alpha: automatic (GrabCut), "
                            "replace it by uploading yours",
                            type="filepath",
                            image_mode=None,
                            sources=["upload"],
                            elem_id="mask",
                            height=160,
                        )
                        mask_is_auto = gr.State("")  # SHA-256 of the automatic mask shown, or ""
                    with gr.Column():
                        hdri = gr.Dropdown(
                            choices=hdris,
                            value=DEFAULT_HDRI if DEFAULT_HDRI in hdris else hdris[0],
                            label="Bundled HDRI",
                            elem_id="hdri",
                        )
                        envfile = gr.File(
                            label="...or upload an .exr/.hdr map (used instead while present)",
                            file_types=list(ENVMAP_SUFFIXES),
                            type="filepath",
                            elem_id="envfile",
                            height=90,
                        )
                        with gr.Accordion(
                            "...or lighting from words (a lighting source)", open=False
                        ):
                            light_source = gr.Dropdown(
                                choices=[
                                    ("none: the map above", ""),
                                    *((n, n) for n in text_sources),
                                ],
                                value="",
                                label="Lighting source (sky: the built-in grammar; others: installed "
                                "plugins, docs/tutorials/skies.md)",
                                elem_id="light_source",
                            )
                            light_text = gr.Textbox(
                                label="Words (press Enter)",
                                placeholder="golden hour from the left",
                                elem_id="light_text",
                            )
                        az = gr.Slider(
                            -180,
                            180,
                            value=0,
                            step=1,
                            label="Camera azimuth (deg)",
                            elem_id="azimuth",
                        )
                        el = gr.Slider(
                            -90,
                            90,
                            value=0,
                            step=1,
                            label="Camera elevation (deg)",
                            elem_id="elevation",
                        )
                        spin = gr.Slider(
                            0,
                            360,
                            value=0,
                            step=1,
                            label="Light spin about up (deg)",
                            elem_id="spin",
                        )
                        with gr.Row():
                            ldr = gr.Image(
                                label="E_L (LDR, camera frame)",
                                interactive=False,
                                buttons=OUTPUT_BUTTONS,
                                format="png",
                                elem_id="ldr",
                                height=140,
                            )
                            hdr = gr.Image(
                                label="E_H (log HDR, camera frame)",
                                interactive=False,
                                buttons=OUTPUT_BUTTONS,
                                format="png",
                                elem_id="hdr",
                                height=140,
                            )
                        view = gr.Image(
                            label="Environment seen from the camera (centre-left: behind the object; "
                            "centre-right: behind the camera)",
                            interactive=False,
                            buttons=OUTPUT_BUTTONS,
                            format="png",
                            elem_id="camera_view",
                            height=140,
                        )
                with gr.Accordion("Sampling and turntable", open=False):
                    with gr.Row():
                        steps = gr.Number(
                            value=None,
                            precision=0,
                            label="Steps (empty: the model's suggestion)",
                            elem_id="steps",
                        )
                        seed = gr.Number(value=0, precision=0, label="Seed", elem_id="seed")
                        frames = gr.Slider(
                            2,
                            engine.config.max_frames,
                            value=12,
                            step=1,
                            label="Turntable frames",
                            elem_id="frames",
                        )
                        fps = gr.Slider(
                            1, 30, value=12, step=1, label="Turntable fps", elem_id="fps"
                        )
                        output_size = gr.Radio(
                            choices=[
                                ("the photo's full size", "photo"),
                                ("the model's object crop", "model"),
                            ],
                            value="photo",
                            label="Output size (turntables: up to --max-turntable-side "
                            f"{engine.config.max_turntable_side} px)",
                            elem_id="output_size",
                        )
                with gr.Row():
                    relight_btn = gr.Button("Relight", variant="primary", elem_id="relight")
                    turntable_btn = gr.Button("Turntable", elem_id="turntable")
                status = gr.Markdown(elem_id="status")
                with gr.Row():
                    prepared = gr.Image(
                        label="Model input (object crop on white)",
                        interactive=False,
                        buttons=OUTPUT_BUTTONS,
                        type="filepath",
                        elem_id="prepared",
                        height=256,
                    )
                    prepared_mask = gr.Image(
                        label="Mask used",
                        interactive=False,
                        buttons=OUTPUT_BUTTONS,
                        type="filepath",
                        elem_id="prepared_mask",
                        height=256,
                    )
                    relit = gr.Image(
                        label="Relit",
                        interactive=False,
                        buttons=OUTPUT_BUTTONS,
                        type="filepath",
                        elem_id="relit",
                        height=256,
                    )
                    spin_gif = gr.Image(
                        label="Turntable",
                        interactive=False,
                        buttons=OUTPUT_BUTTONS,
                        type="filepath",
                        elem_id="turntable_gif",
                        height=256,
                    )
                with gr.Row():
                    relit_dl = gr.DownloadButton(
                        "Download relit PNG", interactive=False, elem_id="download_relit"
                    )
                    gif_dl = gr.DownloadButton(
                        "Download turntable GIF", interactive=False, elem_id="download_gif"
                    )
                    mp4_dl = gr.DownloadButton(
                        "Download turntable MP4",
                        interactive=False,
                        visible=mp4 is not None,
                        elem_id="download_mp4",
                    )
                gr.Markdown(
                    f"*No MP4 download: {MP4_UNAVAILABLE}*" if mp4 is None else "",
                    visible=mp4 is None,
                    elem_id="mp4_note",
                )
            with gr.Tab("Insert into a photo", id="insert_tab", elem_id="insert_tab"):
                build_insert_tab(
                    engine,
                    jobs,
                    model,
                    hdris=hdris,
                    text_sources=text_sources,
                    source_maps=source_maps,
                )

        light_inputs = [model, hdri, envfile, az, el, spin, light_source, light_text]
        previews = [ldr, hdr, view]
        preview_args: dict[str, Any] = {
            "fn": preview,
            "inputs": light_inputs,
            "outputs": previews,
            "concurrency_id": "preview",
            "concurrency_limit": 2,
            "show_progress": "hidden",
        }
        demo.load(api_name="preview", **preview_args)
        for slider in (az, el, spin):
            slider.input(trigger_mode="always_last", api_visibility="private", **preview_args)
        for field in (model, hdri):
            field.change(api_visibility="private", **preview_args)
        envfile.change(api_visibility="private", **preview_args)
        light_source.change(api_visibility="private", **preview_args)
        light_text.submit(api_visibility="private", **preview_args)
        photo.change(
            auto_mask,
            [photo, mask, mask_is_auto],
            [mask, mask_is_auto, status],
            api_name="auto_mask",
            concurrency_id="mask",
            concurrency_limit=1,
        )
        # a mask the user uploads replaces the automatic one and is kept for the next photo
        mask.upload(lambda: "", None, mask_is_auto, api_visibility="private")
        job_inputs = [model, photo, mask, hdri, envfile, az, el, spin, steps, seed, output_size]
        # one sampling job at a time across both buttons (and the API); others wait in the queue
        relight_btn.click(
            relight,
            [*job_inputs, mask_is_auto, light_source, light_text],
            [prepared, prepared_mask, relit, relit_dl, status],
            api_name="relight",
            concurrency_id="model",
            concurrency_limit=1,
        )
        turntable_btn.click(
            turntable,
            [*job_inputs, frames, fps, mask_is_auto, light_source, light_text],
            [spin_gif, gif_dl, mp4_dl, status],
            api_name="turntable",
            concurrency_id="model",
            concurrency_limit=1,
        )
    return demo
