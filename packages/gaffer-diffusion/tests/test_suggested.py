"""A model's suggested sampling travels in its folder."""

import argparse
import json
from pathlib import Path

import pytest

from gaffer_diffusion import cli, pretrained
from gaffer_diffusion.errors import CheckpointMismatchError
from gaffer_diffusion.loading import MANIFEST_NAME, save_pretrained
from gaffer_diffusion.suggested import (
    PAPER_SUGGESTION,
    SuggestedSampling,
    read_default_sampling,
    read_suggested_sampling,
    suggestion_from_training_config,
)
from gaffer_diffusion.testing import tiny_model


def test_shipped_manifest_records_the_documented_setting() -> None:
    # the model card's setting (MODEL_CARD.md "suggested setting"), recorded once in the manifest
    own = read_suggested_sampling(pretrained.gaffer_tiny_path())
    assert own is not PAPER_SUGGESTION
    assert (own.num_inference_steps, own.guidance_scale, own.average_samples) == (1, 1.0, 1)
    assert own.mirror_average is True
    assert own.compat == "default" and own.latent_mode == "mode"
    assert own.object_fraction == 0.75
    assert pretrained.gaffer_tiny_sampling() == own


@pytest.fixture(scope="module")
def own_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    mine = SuggestedSampling(
        num_inference_steps=4, guidance_scale=1.5, compat="default", object_fraction=0.6
    )
    return save_pretrained(tiny_model(), tmp_path_factory.mktemp("m") / "own", suggested=mine)


def test_round_trip_and_paper_fallback(own_folder: Path, tmp_path: Path) -> None:
    got = read_suggested_sampling(own_folder)
    assert (got.num_inference_steps, got.guidance_scale, got.compat, got.object_fraction) == (
        4,
        1.5,
        "default",
        0.6,
    )
    bare = save_pretrained(tiny_model(), tmp_path / "bare")
    assert read_suggested_sampling(bare) is PAPER_SUGGESTION
    assert read_suggested_sampling(tmp_path / "authors-checkpoint-80000") is PAPER_SUGGESTION


def test_malformed_block_is_named(own_folder: Path, tmp_path: Path) -> None:
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(own_folder, bad)
    manifest = json.loads((bad / MANIFEST_NAME).read_text())
    manifest["suggested_sampling"]["compat"] = "srgb"
    (bad / MANIFEST_NAME).write_text(json.dumps(manifest))
    with pytest.raises(CheckpointMismatchError, match=r"suggested_sampling.*compat"):
        read_suggested_sampling(bad)


def _args(checkpoint: Path | None, **kw: object) -> argparse.Namespace:
    base = dict(
        checkpoint=checkpoint,
        compat=None,
        steps=None,
        guidance=None,
        average_samples=None,
        mirror_average=None,
        scheduler="ddim",
        latent_mode=None,
        object_fraction=None,
    )
    base.update(kw)
    return argparse.Namespace(**base)


def test_cli_samples_a_self_trained_model_its_own_way(own_folder: Path) -> None:
    # the bug this fixes: a model trained with the default encoding was relit with the authors'
    args = _args(own_folder)
    assert cli._compat(args) == "default"
    s = cli._sampling(args)
    assert (s.num_inference_steps, s.guidance_scale, s.latent_mode) == (4, 1.5, "mode")
    assert cli._object_fraction(args) == 0.6
    # explicit values still win
    s = cli._sampling(_args(own_folder, steps=9, compat="neural-gaffer"))
    assert s.num_inference_steps == 9 and s.latent_mode == "sample"
    # no --checkpoint: the shipped gaffer-tiny's
    shipped = read_default_sampling(pretrained.gaffer_tiny_path())
    assert cli._sampling(_args(None)).num_inference_steps == shipped.num_inference_steps == 1
    assert cli._compat(_args(None)) == shipped.compat == "default"


def test_training_config_gives_the_suggestion() -> None:
    cfg = {
        "data": {"lighting_compat": "default", "object_fraction": 0.75, "mirror_prob": 0.5},
        "validation": {"num_inference_steps": 1, "guidance_scale": 1.0},
    }
    s = suggestion_from_training_config(cfg)
    assert (s.num_inference_steps, s.guidance_scale, s.mirror_average, s.compat) == (
        1,
        1.0,
        True,
        "default",
    )
    assert s.object_fraction == 0.75


def test_sampling_config_is_built_without_torch_and_is_the_pipelines_class() -> None:
    # `DefaultSampling.sampling_config` runs before the command line imports torch: SamplingConfig
    # lives in the torch-free `sampling_config`, and `pipelines.config` re-exports the same class
    import subprocess
    import sys

    code = (
        "import sys\n"
        "import gaffer_diffusion\n"
        "from gaffer_diffusion.suggested import PAPER_SAMPLING\n"
        "c = PAPER_SAMPLING.sampling_config()\n"
        "assert type(c) is gaffer_diffusion.SamplingConfig, type(c)\n"
        "assert c.num_inference_steps == 50 and c.latent_mode == 'sample', c\n"
        "print(sorted(m for m in ('torch', 'diffusers') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
    from gaffer_diffusion.pipelines.config import SamplingConfig
    from gaffer_diffusion.sampling_config import SamplingConfig as TorchFree

    assert SamplingConfig is TorchFree
