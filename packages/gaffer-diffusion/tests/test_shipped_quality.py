"""Quality regression tests of the shipped learned components on the shipped example.

The example object (`gaffer_diffusion/data/example/`, a faceted icosphere in no training split) ships
with its ground-truth renders under the 8 bundled HDRIs, so the shipped gaffer-tiny can be scored on
it offline in a few seconds. The floors sit below the values measured when the weights were shipped
(`MEASURED_*`; the example's scores equal `gaffer-diffusion demo`'s metrics.json) by a margin that
float-summation order and thread counts cannot cross (sampling is seeded and the model one DDIM step),
and far above the unrelit input. gaffer-normals is checked the same way on held-out views with true
normals.
"""

from pathlib import Path

import numpy as np
import torch

HELD_OUT_NORMALS = Path(__file__).parent / "data" / "held_out_normals.npz"
"""6 views of validation objects the estimator never trained on (`render_val05`: the first view of
every 4th object, 3 procedural and 3 pybullet shapes): input render under lighting 0 on white, mask and
Blender's true camera-frame normals at the estimator's 128 px object-centred crop."""

MEASURED_ESTIMATOR_DEG = 18.32
"""gaffer-normals 1.1's mean angular error on those views when it shipped (1.0: 19.89; the silhouette
dome: 21.64)."""


def test_shipped_normal_estimator_beats_the_dome_on_held_out_views() -> None:
    from gaffer_diffusion.geometry.estimator import estimate_normals, shipped_normal_estimator
    from gaffer_diffusion.hints import silhouette_normals
    from gaffer_diffusion.training.normals import mean_angular_error_deg

    data = np.load(HELD_OUT_NORMALS)
    images = torch.from_numpy(data["images"]).float() / 255.0
    masks = torch.from_numpy(data["masks"]).float() / 255.0
    truth = torch.from_numpy(data["normals_cam"].astype(np.float32))
    with torch.no_grad():
        est = estimate_normals(shipped_normal_estimator(), images, masks)
    dome = silhouette_normals(masks)
    est_deg, dome_deg = (
        mean_angular_error_deg(est, truth, masks),
        mean_angular_error_deg(dome, truth, masks),
    )
    # deterministic float32 inference: 0.5 degree covers summation order across thread counts
    assert est_deg <= MEASURED_ESTIMATOR_DEG + 0.5, f"{est_deg:.2f} deg"
    assert est_deg <= dome_deg - 1.0, f"estimator {est_deg:.2f} deg vs dome {dome_deg:.2f} deg"


MEASURED_EXAMPLE = (18.42, 19.62)
"""gaffer-tiny 0.7's object PSNR (raw, aligned) on the shipped example when it shipped
(`benchmarks/results/demo_example_gaffer-tiny-0.7.json`; 0.6: 18.28 / 19.50)."""


def _score_example() -> tuple[float, float, float, float, float]:
    """(relit raw, relit aligned, input raw, input aligned, share closer) over the object mask,
    with the shipped model's own suggested sampling, as `gaffer-diffusion evaluate` runs it."""
    import pytest

    pytest.importorskip("gaffer_data")
    from gaffer_diffusion.evaluation import (
        dataset_pairs,
        evaluate_dataset,
        suggested_evaluation_config,
    )
    from gaffer_diffusion.pipelines import RelightPipeline
    from gaffer_diffusion.pretrained import example_dataset_path, gaffer_tiny_path, load_gaffer_tiny
    from gaffer_diffusion.suggested import read_suggested_sampling
    from gaffer_envmap.bundled import bundled_hdris

    hdri_dir = next(iter(bundled_hdris().values())).parent
    pairs = dataset_pairs(example_dataset_path(), input_lighting=0, envmap_dirs=[hdri_dir])
    config = suggested_evaluation_config(
        read_suggested_sampling(gaffer_tiny_path()), seed=0, batch_size=4
    )
    result = evaluate_dataset(RelightPipeline(load_gaffer_tiny().model), pairs, config)
    r, b = result.report, result.baseline
    assert r.mean_object_raw is not None and r.mean_object_aligned is not None
    assert b is not None and b.mean_object_raw is not None and b.mean_object_aligned is not None
    return (
        r.mean_object_raw.psnr,
        r.mean_object_aligned.psnr,
        b.mean_object_raw.psnr,
        b.mean_object_aligned.psnr,
        float(result.closer_than_input or 0.0),
    )


def test_shipped_gaffer_tiny_relights_the_example_above_its_floors() -> None:
    raw, aligned, input_raw, input_aligned, closer = _score_example()
    # one seeded DDIM step: 0.5 dB covers float summation order across machines and thread counts;
    # the unrelit input sits more than 6 dB lower, so broken weights or a wrong encoding fail here
    assert raw >= MEASURED_EXAMPLE[0] - 0.5, f"object PSNR {raw:.2f} dB (input {input_raw:.2f})"
    assert aligned >= MEASURED_EXAMPLE[1] - 0.5, (
        f"aligned {aligned:.2f} dB (input {input_aligned:.2f})"
    )
    assert raw >= input_raw + 4.0 and aligned >= input_aligned + 4.0
    assert closer >= 0.9
