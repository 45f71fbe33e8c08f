"""The Gradio page of `gaffer-diffusion app`: widgets wired to `Engine` calls, nothing else.

Import this module only after `server.py` has set Gradio's environment (analytics off, cache folder):
Gradio reads both when it is imported.
"""

import functools
import html
import itertools
import logging
import re
import shutil
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import gradio as gr
import numpy as np
from PIL import Image

from gaffer_diffusion.app.engine import CameraPose, Engine, RelightResult, write_gif
from gaffer_diffusion.errors import GafferDiffusionError

logger = logging.getLogger(__name__)

DEFAULT_HDRI = "sunrise"
"""The bundled map selected when the page opens (the shipped example's input lighting)."""

ENVMAP_SUFFIXES = (".exr", ".hdr")
"""Uploads the environment-map field accepts (gaffer-envmap reads both)."""

OUTPUT_BUTTONS: list[Any] = ["download", "fullscreen"]
"""Buttons on result images (no "share": that uploads to Hugging Face Spaces)."""

KEEP_JOBS = 8
"""Output folders kept on disk; older ones are deleted (Gradio has copied what the page shows)."""

F = TypeVar("F", bound=Callable[..., Any])

_CACHE_DIRS = re.compile(r"[^\s'\"`]*/[0-9a-f]{64}/")
"""Gradio's upload cache folders (`.../<sha256>/`), cut from messages: the file name is what a user knows."""


def _page_message(exc: BaseException) -> str:
    """`exc`'s message for the page: no server paths, HTML special characters escaped."""
    return html.escape(_CACHE_DIRS.sub("", str(exc)), quote=False)


def _shown_in_page(fn: F) -> F:
    """Turn the library's expected errors into a `gr.Error` the page shows as one readable message."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except gr.Error:
            raise
        except Exception as exc:
            # gaffer-envmap's errors (unreadable EXR, not 2:1) carry their own fix, like ours
            ours = isinstance(exc, GafferDiffusionError) or type(exc).__module__.startswith(
                "gaffer_envmap"
            )
            if not ours and not isinstance(exc, OSError | ValueError):
                logger.exception("unexpected error in %s", fn.__name__)
                raise gr.Error(
                    f"Internal error ({type(exc).__name__}); the server log has the details."
                ) from exc
            logger.info("%s refused: %s", fn.__name__, exc)
            raise gr.Error(
                _page_message(exc), title="Cannot relight", print_exception=False
            ) from exc

    return wrapper  # type: ignore[return-value]


class _Jobs:
    """Per-request output folders under the app's temporary root, only the newest `KEEP_JOBS` kept."""

    def __init__(self, root: Path) -> None:
        self._root = root
        self._dirs: deque[Path] = deque()
        self._count = itertools.count()
        self._lock = threading.Lock()

    def new(self) -> Path:
        with self._lock:
            path = self._root / f"job-{next(self._count):06d}"
            path.mkdir(parents=True)
            self._dirs.append(path)
            while len(self._dirs) > KEEP_JOBS:
                shutil.rmtree(self._dirs.popleft(), ignore_errors=True)
        return path


def _save_png(path: Path, arr: np.ndarray) -> str:
    Image.fromarray(arr).save(path)
    return str(path)


def _envmap_path(bundled: str | None, upload: str | None) -> str:
    """The uploaded map if there is one, else the chosen bundled HDRI."""
    from gaffer_envmap.bundled import bundled_hdri

    if upload:
        if Path(upload).suffix.lower() not in ENVMAP_SUFFIXES:
            raise gr.Error(
                f"The environment map must be an .exr or .hdr file, not {html.escape(Path(upload).name, quote=False)}.",
                title="Cannot relight",
                print_exception=False,
            )
        return upload
    if not bundled:
        raise gr.Error("Choose a bundled HDRI or upload an .exr/.hdr map.", print_exception=False)
    return str(bundled_hdri(bundled))


def build_app(engine: Engine, jobs_root: Path) -> gr.Blocks:
    """The page: inputs (photo, mask, model, lighting), live lighting previews, relight, turntable.

    API endpoints (for `gradio_client`): `/preview`, `/relight`, `/turntable`.
    """
    from gaffer_envmap.bundled import bundled_hdris

    jobs = _Jobs(jobs_root)
    hdris = list(bundled_hdris())
    labels = engine.model_labels

    @_shown_in_page
    def preview(
        model: str, hdri: str, envfile: str | None, az: float, el: float, spin: float
    ) -> tuple[Any, ...]:
        shown = engine.preview(
            model,
            _envmap_path(hdri, envfile),
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
        frames: int,
    ) -> tuple[RelightResult, Path, float]:
        if not photo:
            raise gr.Error(
                "Upload a photo of the object first (RGBA, or RGB with a mask).",
                print_exception=False,
            )
        t0 = time.perf_counter()
        prepared = engine.prepare(model, photo, mask or None)
        result = engine.relight(
            model,
            prepared,
            _envmap_path(hdri, envfile),
            CameraPose(
                azimuth_deg=float(pose[0]), elevation_deg=float(pose[1]), spin_deg=float(pose[2])
            ),
            num_inference_steps=None if steps in (None, 0) else int(steps),
            seed=0 if seed is None else int(seed),
            frames=frames,
        )
        return result, jobs.new(), time.perf_counter() - t0

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
    ) -> tuple[Any, ...]:
        result, out, seconds = _run(
            model, photo, mask, hdri, envfile, (az, el, spin), steps, seed, 0
        )
        relit = _save_png(out / "relit.png", result.frames[0])
        size = result.frames[0].shape[0]
        status = (
            f"Relit with {result.model} ({result.steps} step(s)) in {seconds:.1f} s, at the model's "
            f"{size}x{size} px object crop."
        )
        return (
            _save_png(out / "input.png", result.input_rgb),
            _save_png(out / "mask.png", result.mask),
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
        frames: float,
        fps: float,
    ) -> tuple[Any, ...]:
        n = int(frames)
        if n < 2:
            raise gr.Error("A turntable needs 2 or more frames.", print_exception=False)
        result, out, seconds = _run(
            model, photo, mask, hdri, envfile, (az, el, spin), steps, seed, n
        )
        gif = str(write_gif(out / "turntable.gif", result.frames, float(fps)))
        status = f"Turntable of {n} frames with {result.model} in {seconds:.1f} s."
        return gif, gr.DownloadButton(value=gif, interactive=True), status

    with gr.Blocks(
        title="gaffer: relight an object", analytics_enabled=False, delete_cache=(600, 3600)
    ) as demo:
        gr.Markdown(
            "# gaffer: relight an object from one photo\n"
            "Upload a photo of an object (an RGBA PNG with a transparent background, or an RGB photo "
            "and its mask), choose the lighting, and relight. Everything runs on this machine."
        )
        with gr.Row():
            with gr.Column():
                photo = gr.Image(
                    label="Photo (RGBA, or RGB with a mask)",
                    type="filepath",
                    image_mode=None,
                    sources=["upload", "clipboard"],
                    elem_id="photo",
                    height=260,
                )
                mask = gr.Image(
                    label="Mask (white = object), for photos without alpha",
                    type="filepath",
                    image_mode=None,
                    sources=["upload"],
                    elem_id="mask",
                    height=160,
                )
                model = gr.Dropdown(choices=labels, value=labels[0], label="Model", elem_id="model")
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
                az = gr.Slider(
                    -180, 180, value=0, step=1, label="Camera azimuth (deg)", elem_id="azimuth"
                )
                el = gr.Slider(
                    -90, 90, value=0, step=1, label="Camera elevation (deg)", elem_id="elevation"
                )
                spin = gr.Slider(
                    0, 360, value=0, step=1, label="Light spin about up (deg)", elem_id="spin"
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
                fps = gr.Slider(1, 30, value=12, step=1, label="Turntable fps", elem_id="fps")
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

        light_inputs = [model, hdri, envfile, az, el, spin]
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
        job_inputs = [model, photo, mask, hdri, envfile, az, el, spin, steps, seed]
        # one sampling job at a time across both buttons (and the API); others wait in the queue
        relight_btn.click(
            relight,
            job_inputs,
            [prepared, prepared_mask, relit, relit_dl, status],
            api_name="relight",
            concurrency_id="model",
            concurrency_limit=1,
        )
        turntable_btn.click(
            turntable,
            [*job_inputs, frames, fps],
            [spin_gif, gif_dl, status],
            api_name="turntable",
            concurrency_id="model",
            concurrency_limit=1,
        )
    return demo
