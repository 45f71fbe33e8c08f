"""Evaluate a relighting model on a rendered dataset (paper §4, official implementation §5).

A gaffer-data dataset holds, per object and camera view, renders under several environment-map draws
(`lit/{VVV}_{LLL}.png`), the camera pose and which map (and augmentation) lit each render. Evaluation
pairs one render of a view (the *input*, lighting `input_lighting`, or the area-light render) with every
other lighting of the same view (the *targets*), as the paper's protocol does (input and target share
the camera; only the lighting changes). For each pair the model relights the input under the target's
environment map, rotated into the view's camera frame by gaffer-envmap (`compat="neural-gaffer"` by
default, the encoding of the released checkpoint), and the prediction is scored against the target
render with `gaffer_diffusion.metrics`: PSNR, SSIM and the perceptual distance, raw and channel-aligned
(means over the whole image and over the object mask), per pair and averaged.

Datasets converted from the authors' released validation layout (`gaffer-data convert-authors`, schema
"gaffer.authors_dataset") are read too: there the target lighting comes as the authors' pre-encoded
camera-frame LDR/HDR maps (`envmap_ldr/`, `envmap_hdr/`), used as they are (no env map, no `compat`).

Images are scored the way the authors score them: full frame, object composited on a white background,
prediction quantised to 8 bits. Renders at another resolution than the model's are resized before use,
for input and target alike, by the reader training uses (`gaffer_diffusion.images.load_rgba_on_white`:
bilinear, antialiased).

gaffer-data is imported lazily, only here: `pip install "gaffer-diffusion[eval]"`.
"""

from gaffer_diffusion.evaluation.images import (
    _to_chw,
    pair_crop_box,
    quantize_8bit,
    read_mask,
    read_rgba_on_white,
)
from gaffer_diffusion.evaluation.lighting import pair_lighting, read_lighting_map
from gaffer_diffusion.evaluation.pairs import dataset_kind, dataset_pairs
from gaffer_diffusion.evaluation.records import (
    ENVMAP_SUFFIXES,
    DatasetEvaluation,
    DatasetKind,
    EncodedLightingFiles,
    EnvmapLighting,
    EvalPair,
    EvaluationConfig,
    InputLighting,
    suggested_evaluation_config,
)
from gaffer_diffusion.evaluation.run import evaluate_dataset

__all__ = [
    "ENVMAP_SUFFIXES",
    "DatasetEvaluation",
    "DatasetKind",
    "EncodedLightingFiles",
    "EnvmapLighting",
    "EvalPair",
    "EvaluationConfig",
    "InputLighting",
    "_to_chw",
    "dataset_kind",
    "dataset_pairs",
    "evaluate_dataset",
    "pair_crop_box",
    "pair_lighting",
    "quantize_8bit",
    "read_lighting_map",
    "read_mask",
    "read_rgba_on_white",
    "suggested_evaluation_config",
]
