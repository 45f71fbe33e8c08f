"""The end-to-end relighting demo (README's main job): `gaffer-diffusion demo --out DIR`.

Offline and CPU-friendly. It loads gaffer-tiny (the 128 px model shipped inside this package) or a
`--checkpoint`, reads the shipped example object (a gaffer-data render: one view of a held-out object
with ground-truth renders under the bundled CC0 HDRIs), and relights the object's input view

1. under every lighting that has a ground-truth render (scored: PSNR, SSIM and the perceptual metric,
   raw and channel-aligned, beside two baselines: the unrelit input, and the input channel-aligned to
   the target),
2. under every other bundled HDRI (no ground truth: pictures only),
3. under a bundled HDRI spun about world up over `frames` steps (a turntable GIF; by default the
   HDRI whose diffuse light changes most with the spin, `DemoConfig.turntable_hdri`).

All lightings go through the same batched sampling calls with one seed (a result does not depend on
the batch it landed in). It writes, under `out`: the images as PNGs (`inputs/`, `lighting/`, `relit/`,
`ground_truth/`, `turntable/`), `turntable.gif`, `overview.png`, `metrics.json` and a self-contained
`report.html` that links to them by relative path. Every file is written atomically.

Evaluation protocol as in `gaffer_diffusion.evaluation`: full frame, object on white, prediction
quantised to 8 bits; renders at another resolution than the model's are resized (PIL bicubic).

The code: `config.py` holds `DemoConfig` and the sampling defaults; `model.py` loads the model and
picks its sampling (`load_model`, `sampling_for`); `example.py` reads the example view;
`lightings.py` builds the relighting jobs and `turntable.py` the turntable's HDRI and GIF;
`sampling.py` runs the batched sampling; `writing.py` writes the images; `metrics_document.py`
builds the metrics document (a frozen dataclass, written as `metrics.json`), which
`report_content.py` reads for `report.html`; `run.py` holds `run_demo`, which ties them together,
and `DemoResult`.
"""

from gaffer_diffusion.demo.config import DEFAULT_GUIDANCE, DEFAULT_STEPS, DemoConfig, InputChoice
from gaffer_diffusion.demo.example import _read_example
from gaffer_diffusion.demo.lightings import _lightings
from gaffer_diffusion.demo.metrics_document import METRICS_SCHEMA, METRICS_SCHEMA_VERSION
from gaffer_diffusion.demo.model import LoadedModel, load_model, sampling_for
from gaffer_diffusion.demo.run import DEMO_OUTPUTS, DemoResult, run_demo
from gaffer_diffusion.demo.turntable import GIF_SCALE

# the names other modules, tests and tools import from `gaffer_diffusion.demo` (the module this was)
__all__ = [
    "DEFAULT_GUIDANCE",
    "DEFAULT_STEPS",
    "DEMO_OUTPUTS",
    "GIF_SCALE",
    "METRICS_SCHEMA",
    "METRICS_SCHEMA_VERSION",
    "DemoConfig",
    "DemoResult",
    "InputChoice",
    "LoadedModel",
    "_lightings",
    "_read_example",
    "load_model",
    "run_demo",
    "sampling_for",
]
