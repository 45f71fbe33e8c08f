"""`gaffer-diffusion app`: relight an object photo in the browser (extra `[app]`, Gradio 6).

Importing this package does not import Gradio; `serve` does, after setting its environment.
"""

from gaffer_diffusion.app.config import AppConfig, ModelChoice, add_app_arguments, config_from_args
from gaffer_diffusion.app.server import run_app, serve

__all__ = ["AppConfig", "ModelChoice", "add_app_arguments", "config_from_args", "run_app", "serve"]
