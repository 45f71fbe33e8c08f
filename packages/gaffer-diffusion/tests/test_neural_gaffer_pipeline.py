"""`NeuralGafferPipeline`: a diffusers `DiffusionPipeline` that gives the same pixels as
`gaffer-diffusion relight PHOTO --envmap MAP --seed S` (shipped gaffer-tiny weights), loads our
folders and the authors' release from local folders only, and round-trips through save_pretrained."""

from pathlib import Path

import numpy as np
import pytest
import torch
from diffusers.pipelines.pipeline_utils import DiffusionPipeline
from PIL import Image

from gaffer_diffusion import NeuralGafferPipeline, pretrained
from gaffer_diffusion.cli import main
from gaffer_diffusion.errors import ConfigError
from gaffer_diffusion.testing import tiny_model, write_fake_authors_checkpoint, write_fake_zero123
from gaffer_envmap import EnvironmentMap
from gaffer_envmap.io import write_envmap

pytestmark = pytest.mark.skipif(
    not (pretrained.gaffer_tiny_path() / "gaffer_model.json").is_file(),
    reason="gaffer-tiny weights not in the package",
)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A 70x90 RGBA photo (textured object in its alpha) and a map with one bright window."""
    root = tmp_path_factory.mktemp("ngp")
    rng = np.random.default_rng(0)
    rgba = np.zeros((90, 70, 4), np.uint8)
    rgba[..., :3] = rng.integers(40, 220, (90, 70, 3))
    rgba[20:70, 15:55, 3] = 255
    Image.fromarray(rgba).save(root / "obj.png")
    env = np.full((16, 32, 3), 0.3, np.float32)
    env[2:6, 4:10] = 5.0
    write_envmap(root / "env.exr", EnvironmentMap(radiance_linear=env))
    return root / "obj.png", root / "env.exr"


@pytest.fixture(scope="module")
def pipe() -> NeuralGafferPipeline:
    return NeuralGafferPipeline.from_pretrained(None)  # the shipped gaffer-tiny


def _cli(photo: Path, env: Path, out: Path, seed: int) -> np.ndarray:
    args = ["relight", str(photo), "--envmap", str(env), "--seed", str(seed)]
    assert main([*args, "--azimuth", "0", "--elevation", "0", "--out", str(out)]) == 0
    return np.asarray(Image.open(out)).astype(int)


def test_same_pixels_as_the_relight_command(
    pipe: NeuralGafferPipeline, inputs: tuple[Path, Path], tmp_path: Path
) -> None:
    photo, env = inputs
    assert isinstance(pipe, DiffusionPipeline)
    assert set(pipe.components) == {"unet", "vae", "image_encoder", "scheduler"}
    assert pipe.model_cpu_offload_seq == "image_encoder->unet->vae"
    for seed in (0, 7):
        want = _cli(photo, env, tmp_path / f"cli{seed}.png", seed)
        got = pipe(Image.open(photo), env, generator=torch.Generator().manual_seed(seed))
        (image,) = got.images
        assert image.size == (70, 90) and image.mode == "RGBA"  # the photo's size, alpha kept
        diff = np.abs(np.asarray(image).astype(int) - want)
        assert int(diff.max()) <= 1, f"seed {seed}: {int(diff.max())} levels off the CLI"
    # not a no-op: the object is relit, the background is the photo's bytes
    src = np.asarray(Image.open(photo)).astype(int)
    obj = src[..., 3] > 0
    assert float(np.abs(want[obj, :3] - src[obj, :3]).mean()) > 2.0
    assert np.array_equal(want[~obj], src[~obj])


def test_overrides_output_type_and_callback(
    pipe: NeuralGafferPipeline, inputs: tuple[Path, Path]
) -> None:
    photo, env = inputs
    seen: list[tuple[int, int]] = []

    def on_step(p: object, step: int, t: int, kw: dict) -> dict:
        assert p is pipe
        seen.append((step, t))
        return kw

    out = pipe(photo, env, num_inference_steps=3, output_type="np", callback_on_step_end=on_step)
    images = out.images
    assert isinstance(images, np.ndarray) and images.shape == (1, 90, 70, 4)
    assert images.dtype == np.float32 and 0.0 <= images.min() and images.max() <= 1.0
    assert [s for s, _ in seen] == [0, 1, 2] and seen[0][1] > seen[-1][1]  # 3 steps, t falling
    with pytest.raises(ConfigError, match="output_type"):
        pipe(photo, env, output_type="latent")
    with pytest.raises(ConfigError, match="w2c"):
        pipe(photo, env, w2c=np.eye(2))


def test_save_and_load_round_trip_and_local_folders_only(
    pipe: NeuralGafferPipeline, inputs: tuple[Path, Path], tmp_path: Path
) -> None:
    photo, env = inputs
    pipe.save_pretrained(tmp_path / "saved")
    again = NeuralGafferPipeline.from_pretrained(tmp_path / "saved")
    assert again.default_sampling.to_json() == pipe.default_sampling.to_json()
    a = np.asarray(pipe(photo, env, generator=3).images[0])
    b = np.asarray(again(photo, env, generator=3).images[0])
    assert np.array_equal(a, b)
    with pytest.raises(ConfigError, match="revision"):
        NeuralGafferPipeline.from_pretrained(tmp_path / "saved", revision="main")
    with pytest.raises(FileNotFoundError, match="pretrained_model_name_or_path"):
        NeuralGafferPipeline.from_pretrained("someone/neural-gaffer")  # a hub id: refused
    with pytest.raises(ConfigError, match="components alone"):
        NeuralGafferPipeline(pipe.unet, pipe.vae, pipe.image_encoder, pipe.scheduler)


def test_the_authors_release_with_its_base_model(tmp_path: Path) -> None:
    """The latent (authors') kind of model: checkpoint-80000/ + Zero-1-to-3 XL, random stand-ins."""
    model = tiny_model()
    ckpt = write_fake_authors_checkpoint(model, tmp_path / "checkpoint-80000")
    base = write_fake_zero123(model, tmp_path / "zero123-xl")
    with pytest.raises(ConfigError, match="base_model"):
        NeuralGafferPipeline.from_pretrained(ckpt)
    pipe = NeuralGafferPipeline.from_pretrained(ckpt, base)
    assert pipe.default_sampling.compat == "neural-gaffer"  # the paper's: 50 steps, guidance 3
    rgba = np.zeros((40, 30, 4), np.uint8)
    rgba[..., :3] = 120
    rgba[8:30, 5:25, 3] = 255
    env = EnvironmentMap(radiance_linear=np.full((8, 16, 3), 0.5, np.float32))
    out = pipe(Image.fromarray(rgba), env, num_inference_steps=2).images[0]
    assert out.size == (30, 40)
    for name, p in model.unet.state_dict().items():  # the release's UNet, not the base model's
        torch.testing.assert_close(pipe.unet.state_dict()[name], p)
