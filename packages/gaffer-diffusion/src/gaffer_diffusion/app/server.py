"""Start and stop `gaffer-diffusion app`: Gradio's environment, launch options and clean-up.

Everything the app writes (Gradio's upload cache and our outputs) lives under one temporary folder,
removed when the server stops (Ctrl-C or SIGTERM), so a session leaves nothing behind.
"""

import argparse
import logging
import os
import shutil
import signal
import tempfile
from pathlib import Path
from types import FrameType

from gaffer_diffusion.app.config import AppConfig, config_from_args
from gaffer_diffusion.errors import MissingDependencyError

logger = logging.getLogger(__name__)

GRADIO_REQUIREMENT = "gradio>=6,<7"
"""The Gradio line the page is written against (its launch and event options changed in 6)."""


def _import_gradio() -> None:
    try:
        import gradio  # noqa: F401
    except ImportError as exc:
        raise MissingDependencyError(
            f'The app needs the app extra ({exc.name} is missing): pip install "gaffer-diffusion[app]"'
        ) from exc


def _raise_interrupt(signum: int, frame: FrameType | None) -> None:
    raise KeyboardInterrupt  # Gradio's blocking loop closes the server on it; then our finally runs


def serve(config: AppConfig) -> int:
    """Run the app until interrupted; returns the exit status.

    Raises:
        MissingDependencyError: Gradio is not installed (the message has the pip command).
    """
    root = Path(tempfile.mkdtemp(prefix="gaffer-app-"))
    # Gradio reads these when imported: no telemetry or version check, its cache inside our folder.
    os.environ["GRADIO_ANALYTICS_ENABLED"] = "False"
    os.environ["GRADIO_TEMP_DIR"] = str(root / "gradio")
    # torch's compiler cache defaults to $TMPDIR/torchinductor_$USER and outlived the server: keep
    # it in the server's own folder, removed when it stops
    os.environ.setdefault("TORCHINDUCTOR_CACHE_DIR", str(root / "torchinductor"))
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        _import_gradio()
        if config.threads is not None:
            import torch

            torch.set_num_threads(config.threads)
        from PIL import Image

        # Gradio opens every uploaded image with PIL before our handlers run; PIL's own bomb check
        # (> 179 MP) then failed inside Gradio with a many-line message naming the server's paths.
        # Uploads are only opened there (header read: every image input is a file path with
        # image_mode None), and each handler checks width x height against `--max-image-side` and
        # `--max-image-megapixels` before decoding (`Engine._check_image`), refusing in one line.
        Image.MAX_IMAGE_PIXELS = None
        from gaffer_diffusion.app._ui import build_app
        from gaffer_diffusion.app.engine import Engine

        engine = Engine(config)
        engine.model(engine.model_labels[0])  # load the default model before the page opens
        demo = build_app(engine, root / "jobs")
        # the queue is bounded: a request beyond `queue_size` waiting ones is refused at once
        # ("Queue is full"), so a burst of clients cannot pile up uploads and memory
        demo.queue(max_size=config.queue_size, default_concurrency_limit=1)
        # uploads and results live in Gradio's cache under our folder: delete those older than
        # `cache_max_age_s` while serving (Gradio's sweeper), not only when the server stops
        demo.delete_cache = (config.cache_sweep_s, config.cache_max_age_s)
        if config.host not in ("127.0.0.1", "localhost", "::1"):
            logger.warning(
                "binding %s: anyone who can reach this machine can use the app (no authentication)",
                config.host,
            )
        demo.launch(
            server_name=config.host,
            server_port=config.port,
            max_file_size=config.max_upload_bytes,
            show_error=True,
            share=False,
            ssr_mode=False,
            pwa=False,
            mcp_server=False,
            enable_monitoring=False,
            inbrowser=False,
        )
    except KeyboardInterrupt:
        logger.info("stopped")
    finally:
        signal.signal(signal.SIGTERM, previous)
        shutil.rmtree(root, ignore_errors=True)
    return 0


def run_app(args: argparse.Namespace) -> int:
    """`gaffer-diffusion app`: check the flags (before anything heavy loads), then `serve`."""
    return serve(config_from_args(args))
