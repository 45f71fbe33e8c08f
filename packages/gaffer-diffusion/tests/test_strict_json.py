"""Reports are strict JSON: an infinite PSNR (identical images) is null plus a flag."""

import json
import math

import numpy as np
import pytest
from PIL import Image

from gaffer_diffusion._json import NON_FINITE_KEY, json_dumps


def _strict(text: str) -> object:
    def refuse(constant: str) -> None:
        raise ValueError(f"non-standard JSON constant {constant}")

    return json.loads(text, parse_constant=refuse)


def test_non_finite_numbers_become_null_and_are_listed() -> None:
    doc = _strict(json_dumps({"a": [1.0, math.inf], "b": {"c/d": -math.inf, "e": math.nan}}))
    assert doc == {
        "a": [1.0, None],
        "b": {"c/d": None, "e": None},
        NON_FINITE_KEY: {"/a/1": "inf", "/b/c~1d": "-inf", "/b/e": "nan"},
    }
    assert NON_FINITE_KEY not in _strict(json_dumps({"a": 1.0}))


def test_identical_images_score_null_psnr_in_the_report() -> None:
    import torch

    from gaffer_diffusion.metrics import evaluate_images

    img = torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(0))
    report = evaluate_images(img, img.clone(), names=["a", "b"], perceptual=None)
    assert math.isinf(report.items[0].raw.psnr)  # the Python value stays what it is
    doc = _strict(report.to_json())
    assert doc["items"][0]["raw"]["psnr"] is None and doc["mean_raw"]["psnr"] is None
    assert doc[NON_FINITE_KEY]["/items/0/raw/psnr"] == "inf"


def test_cli_evaluate_json_of_identical_folders_is_strict(tmp_path) -> None:
    from gaffer_diffusion.cli import main

    for d in ("p", "g"):
        (tmp_path / d).mkdir()
        img = np.random.default_rng(0).integers(0, 255, (16, 16, 3), dtype=np.uint8)
        Image.fromarray(img).save(tmp_path / d / "x.png")
    args = ["evaluate", "--pred", str(tmp_path / "p"), "--gt", str(tmp_path / "g")]
    assert main([*args, "--no-perceptual", "--json", str(tmp_path / "r.json")]) == 0
    text = (tmp_path / "r.json").read_text()
    assert "Infinity" not in text and "NaN" not in text
    doc = _strict(text)
    assert doc["items"][0]["raw"]["psnr"] is None
    assert doc[NON_FINITE_KEY]["/items/0/raw/psnr"] == "inf"
    with pytest.raises(ValueError, match="non-standard"):
        _strict('{"psnr": Infinity}')  # the check itself refuses what used to be written
