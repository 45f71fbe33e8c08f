"""LoadModel, Relight, Turntable and Insert on small tensors and on the shipped example photo; the
Relight node and the example workflow against `gaffer-diffusion relight` (a subprocess), Turntable and
Insert against the same commands run in-process. gaffer-tiny (128 px, one DDIM step) keeps it fast."""

import json
import shutil
import subprocess
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest
import torch
from PIL import Image

PACK = Path(__file__).resolve().parent.parent
AZIMUTH, ELEVATION, SEED = 45.0, 15.0, 7
"""The camera and seed of the CLI comparison (the example workflow uses the same)."""

LOADIMAGE = "black = object (LoadImage)"


def _levels(image: torch.Tensor) -> np.ndarray:
    return np.round(image.numpy() * 255.0).astype(np.int32)


def _png_rgb(path: Path) -> np.ndarray:
    return np.asarray(Image.open(path).convert("RGB")).astype(np.int32)


@pytest.fixture(scope="module")
def cli_relit(photo_path: Path, tmp_path_factory: pytest.TempPathFactory) -> np.ndarray:
    """`gaffer-diffusion relight` on the example photo under 'courtyard' (a subprocess, as a user
    runs it): `[H, W, 3]` 8-bit levels."""
    out = tmp_path_factory.mktemp("cli") / "relit.png"
    cmd = [
        sys.executable, "-m", "gaffer_diffusion.cli", "relight", str(photo_path),
        "--envmap", "courtyard", "--azimuth", str(AZIMUTH), "--elevation", str(ELEVATION),
        "--seed", str(SEED), "--device", "cpu", "--out", str(out),
    ]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    return _png_rgb(out)


@pytest.fixture(scope="module")
def courtyard(nodes: dict[str, type]) -> Any:
    return nodes["NeuralGafferLoadEnvmap"]().load("courtyard", "raise")[0]


def _relight(nodes: dict[str, type], tiny: Any, image: Any, env: Any, **kw: Any) -> Any:
    args = {
        "mask_sense": LOADIMAGE, "azimuth": AZIMUTH, "elevation": ELEVATION, "seed": SEED,
        "steps": 0, "guidance": -1.0, "output_size": "input", "detail": "transfer",
        "background": "input",
    }  # fmt: skip
    return nodes["NeuralGafferRelight"]().relight(tiny, image, env, **{**args, **kw})


def test_load_model_gaffer_tiny(tiny: Any, lib: ModuleType) -> None:
    assert isinstance(tiny, lib.GafferModel) and tiny.name == "gaffer-tiny" and tiny.size == 128
    assert tiny.compat == "default"
    s = tiny.sampling(0, -1.0)  # the model's own, from its folder (as the CLI reads it)
    assert (s.num_inference_steps, s.guidance_scale) == (
        tiny.suggested.num_inference_steps,
        tiny.suggested.guidance_scale,
    )
    assert tiny.sampling(3, 2.0).num_inference_steps == 3


def test_load_model_folder_relights_with_its_own_settings(
    nodes: dict[str, type], courtyard: Any, tmp_path: Path
) -> None:
    """One of our model folders (a random-init `tiny` preset saved with its own suggested
    sampling) loads through the node, which samples with that suggestion, and relights."""
    from gaffer_diffusion.loading import save_pretrained
    from gaffer_diffusion.suggested import SuggestedSampling
    from gaffer_diffusion.testing import tiny_model

    own = SuggestedSampling(num_inference_steps=2, guidance_scale=1.0, compat="default")
    save_pretrained(tiny_model(), tmp_path / "m", suggested=own)
    (model,) = nodes["NeuralGafferLoadModel"]().load(str(tmp_path / "m"), "", "cpu", "float32")
    assert (
        model.suggested.num_inference_steps == 2 and model.sampling(0, -1.0).guidance_scale == 1.0
    )
    image = torch.rand(1, 24, 24, 3, generator=torch.Generator().manual_seed(1))
    mask = torch.zeros(1, 24, 24)
    mask[:, 6:18, 8:16] = 1.0
    out, _ = _relight(nodes, model, image, courtyard, mask=mask, mask_sense="white = object")
    assert out.shape == (1, 24, 24, 3)


def test_load_model_refusals(nodes: dict[str, type], tmp_path: Path) -> None:
    load = nodes["NeuralGafferLoadModel"]().load
    with pytest.raises(ValueError, match="`model` '/no/such/folder' is not an existing folder"):
        load("/no/such/folder", "", "cpu", "float32")
    with pytest.raises(ValueError, match="needs `base_model`"):
        load(str(tmp_path), "", "cpu", "float32")
    with pytest.raises(ValueError, match="`base_model` goes with the authors' release"):
        load("gaffer-tiny", str(tmp_path), "cpu", "float32")
    with pytest.raises(ValueError, match="`device` is 'tpu'"):
        load("gaffer-tiny", "", "tpu", "float32")


def test_relight_node_matches_the_cli(
    nodes: dict[str, type], tiny: Any, photo: Any, courtyard: Any, cli_relit: np.ndarray
) -> None:
    """The node on LoadImage's IMAGE and MASK gives `gaffer-diffusion relight`'s PNG within one
    8-bit level (measured: identical), at the photo's size; its MASK is LoadImage's, unchanged."""
    image, mask = photo
    out, out_mask = _relight(nodes, tiny, image, courtyard, mask=mask)
    assert out.shape == image.shape and out.dtype == torch.float32
    diff = np.abs(_levels(out[0]) - cli_relit)
    assert int(diff.max()) <= 1, f"max difference {int(diff.max())} levels"
    assert out_mask.shape == mask.shape and torch.allclose(out_mask, mask, atol=1e-6)
    outside = mask[0].numpy() >= 1.0  # alpha 0: the input's bytes, exactly
    assert np.array_equal(_levels(out[0])[outside], _levels(image[0])[outside])


def test_both_mask_senses_and_the_alpha_give_the_same_result(
    nodes: dict[str, type], tiny: Any, photo: Any, courtyard: Any
) -> None:
    image, mask = photo
    a, _ = _relight(nodes, tiny, image, courtyard, mask=mask)
    b, b_mask = _relight(
        nodes, tiny, image, courtyard, mask=1.0 - mask, mask_sense="white = object"
    )
    rgba = torch.cat([image, (1.0 - mask)[..., None]], dim=-1)  # an IMAGE with alpha, no MASK
    c, _ = _relight(nodes, tiny, rgba, courtyard)
    assert int(np.abs(_levels(a) - _levels(b)).max()) <= 1
    assert int(np.abs(_levels(a) - _levels(c)).max()) <= 1
    assert torch.allclose(b_mask, 1.0 - mask, atol=1e-6)  # the output MASK in the input's sense
    with pytest.raises(
        ValueError, match=r"whole border as the object.*inverted; flip `mask_sense`"
    ):
        _relight(nodes, tiny, image, courtyard, mask=mask, mask_sense="white = object")
    with pytest.raises(
        ValueError, match="marks the whole picture as the object; flip `mask_sense`"
    ):
        _relight(nodes, tiny, image, courtyard, mask=torch.zeros_like(mask))


def test_relight_small_batch_output_size_and_backdrop(
    nodes: dict[str, type], tiny: Any, courtyard: Any
) -> None:
    """A batch of two 40 x 56 pictures with a segmenter's MASK (object white): the output keeps the
    input's size and batch, the model crop is 128 px, and `background` envmap changes only the
    pixels around the object."""
    g = torch.Generator().manual_seed(0)
    image = torch.rand(2, 40, 56, 3, generator=g)
    yy, xx = torch.meshgrid(torch.arange(40), torch.arange(56), indexing="ij")
    disc = (((yy - 20) ** 2 + (xx - 28) ** 2) < 12**2).float()
    mask = torch.stack([disc, disc.roll(4, 1)])
    kw = {"mask": mask, "mask_sense": "white = object"}
    out, out_mask = _relight(nodes, tiny, image, courtyard, **kw)
    assert out.shape == (2, 40, 56, 3) and out_mask.shape == (2, 40, 56)
    assert float(out.min()) >= 0.0 and float(out.max()) <= 1.0
    assert torch.equal(out_mask, mask)
    crop, crop_mask = _relight(
        nodes,
        tiny,
        image[:1],
        courtyard,
        output_size="model",
        mask=mask[:1],
        mask_sense="white = object",
    )
    assert crop.shape == (1, 128, 128, 3) and crop_mask.shape == (1, 128, 128)
    framed, _ = _relight(nodes, tiny, image, courtyard, background="envmap", **kw)
    inside = mask.numpy() >= 1.0
    assert np.array_equal(_levels(framed)[inside], _levels(out)[inside])
    assert not np.array_equal(_levels(framed)[~inside], _levels(out)[~inside])


def test_relight_camera_from_w2c_equals_the_angles(
    nodes: dict[str, type], tiny: Any, photo: Any, courtyard: Any, tmp_path: Path
) -> None:
    from gaffer_envmap.poses import orbit_w2c_blender

    image, mask = photo
    by_angles, _ = _relight(nodes, tiny, image, courtyard, mask=mask)
    matrix = orbit_w2c_blender(AZIMUTH, ELEVATION).matrix
    text = " ".join(repr(float(x)) for x in matrix.ravel())
    by_text, _ = _relight(nodes, tiny, image, courtyard, mask=mask, azimuth=0.0, w2c=text)
    np.save(tmp_path / "w2c.npy", matrix)
    by_npy, _ = _relight(nodes, tiny, image, courtyard, mask=mask, w2c=str(tmp_path / "w2c.npy"))
    assert torch.equal(by_angles, by_text) and torch.equal(by_angles, by_npy)


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"image": torch.rand(1, 32, 32)}, "`image` has shape (1, 32, 32); expected an IMAGE"),
        ({"image": torch.full((1, 32, 32, 3), 2.0)}, "`image` holds values outside [0, 1]"),
        ({"mask": torch.zeros(1, 64, 64)}, "LoadImage gives an empty 64x64 MASK"),
        ({"mask": torch.zeros(1, 128, 128), "mask_sense": "white = object"}, "marks no object"),
        ({"mask_sense": "sideways"}, "`mask_sense` is 'sideways'"),
        ({"elevation": 95.0}, "`elevation` is 95.0; pass a number in [-90, 90]"),
        ({"w2c": "1 2 3"}, "`w2c` holds 3 numbers; give 12 (3x4) or 16 (4x4)"),
        ({"w2c": "1 0 0 0  0 1 0 0  0 0 2 0"}, "NeuralGafferRelight: `w2c`"),
        ({"steps": -1}, "`steps` is -1; pass 0 (the model's own)"),
        ({"output_size": "huge"}, "`output_size` is 'huge'"),
        ({"envmap": torch.ones(1, 8, 16, 3)}, "`envmap` is a Tensor; connect a GAFFER_ENVMAP"),
    ],
)
def test_relight_refusals_are_one_line_value_errors(
    nodes: dict[str, type], tiny: Any, photo: Any, courtyard: Any, change: dict, words: str
) -> None:
    image, mask = photo
    kw = {"image": image, "envmap": courtyard, "mask": mask, **change}
    with pytest.raises(ValueError) as info:
        _relight(nodes, tiny, kw.pop("image"), kw.pop("envmap"), **kw)
    assert words in str(info.value) and "\n" not in str(info.value)
    assert str(info.value).startswith("NeuralGafferRelight: ")


def test_turntable_matches_the_cli(
    nodes: dict[str, type], tiny: Any, photo: Any, courtyard: Any, photo_path: Path, tmp_path: Path
) -> None:
    """Three frames equal `gaffer-diffusion relight --turntable 3`'s PNGs within one level."""
    from gaffer_diffusion.cli import main

    image, mask = photo
    (frames,) = nodes["NeuralGafferTurntable"]().turntable(
        tiny, image, courtyard, LOADIMAGE, AZIMUTH, ELEVATION, SEED, 0, -1.0, "input",
        "transfer", "input", 3, mask=mask,
    )  # fmt: skip
    assert frames.shape == (3, *image.shape[1:])
    argv = [
        "relight", str(photo_path), "--envmap", "courtyard", "--azimuth", str(AZIMUTH),
        "--elevation", str(ELEVATION), "--seed", str(SEED), "--device", "cpu",
        "--turntable", "3", "--video", "gif", "--out", str(tmp_path / "spin.png"),
    ]  # fmt: skip
    assert main(argv) == 0
    for k in range(3):
        cli = _png_rgb(tmp_path / f"spin_{k:03d}.png")
        assert int(np.abs(_levels(frames[k]) - cli).max()) <= 1, k
    assert not torch.equal(frames[0], frames[1])  # the light turned
    with pytest.raises(ValueError, match="`frames` is 1; pass an integer in"):
        nodes["NeuralGafferTurntable"]().turntable(
            tiny, image, courtyard, LOADIMAGE, 0.0, 0.0, 0, 0, -1.0, "input", "transfer",
            "input", 1, mask=mask,
        )  # fmt: skip


@pytest.fixture(scope="module")
def background_png(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 120 x 90 background: the level camera's view of the bundled 'forest' HDRI."""
    from gaffer_diffusion.insert_geometry import LEVEL_CAMERA
    from gaffer_diffusion.photo import envmap_backdrop
    from gaffer_envmap.bundled import read_bundled_hdri

    env = read_bundled_hdri("forest")
    view = envmap_backdrop(env.radiance_linear, LEVEL_CAMERA.rotation, height=90, width=120)
    path = tmp_path_factory.mktemp("bg") / "bg.png"
    Image.fromarray(np.round(view * 255).astype(np.uint8)).save(path)
    return path


def test_insert_matches_the_cli(
    nodes: dict[str, type],
    tiny: Any,
    photo: Any,
    photo_path: Path,
    background_png: Path,
    load_image: Any,
    tmp_path: Path,
) -> None:
    """The object put into the background under the map built from it plus a key light equals
    `gaffer-diffusion insert --key-light 135,40,3,5 --at 60,80 --height 50` within one level."""
    from gaffer_diffusion.cli import main

    image, mask = photo
    background, _ = load_image(background_png)
    out, placed, lighting = nodes["NeuralGafferInsert"]().insert(
        tiny, image, background, LOADIMAGE, 60, 80, 50.0, 39.6, 135.0, 40.0, 3.0, 5.0, "2d",
        "transfer", SEED, 0, -1.0, mask=mask,
    )  # fmt: skip
    assert out.shape == background.shape and placed.shape == (1, 90, 120)
    assert lighting.radiance_linear.dtype == np.float32 and lighting.radiance_linear.max() > 1.0
    argv = [
        "insert", str(photo_path), "--into", str(background_png), "--out", str(tmp_path / "in.png"),
        "--key-light", "135,40,3,5", "--at", "60,80", "--height", "50", "--seed", str(SEED),
        "--device", "cpu",
    ]  # fmt: skip
    assert main(argv) == 0
    diff = np.abs(_levels(out[0]) - _png_rgb(tmp_path / "in.png"))
    assert int(diff.max()) <= 1, f"max difference {int(diff.max())} levels"
    rows = np.nonzero((1.0 - placed[0].numpy()) > 0.5)[0]  # LoadImage sense: the object is black
    assert rows.max() == 80


def test_insert_under_a_given_map_and_refusals(
    nodes: dict[str, type],
    tiny: Any,
    photo: Any,
    courtyard: Any,
    background_png: Path,
    load_image: Any,
) -> None:
    image, mask = photo
    background, _ = load_image(background_png)
    insert = nodes["NeuralGafferInsert"]().insert
    args = [tiny, image, background, LOADIMAGE, -1, -1, 0.0, 39.6, 135.0, 40.0, 0.0, 5.0, "none"]
    out, _, lighting = insert(*args, "transfer", 0, 0, -1.0, mask=mask, envmap=courtyard)
    assert out.shape == background.shape and lighting.envmap is courtyard.envmap
    with pytest.raises(ValueError, match="`at_x` is 500; pass -1"):
        insert(tiny, image, background, LOADIMAGE, 500, 10, *args[6:], "transfer", 0, 0, -1.0)
    with pytest.raises(ValueError, match="a connected `envmap` brings its own light"):
        insert(*args[:10], 3.0, 5.0, "2d", "transfer", 0, 0, -1.0, mask=mask, envmap=courtyard)
    with pytest.raises(ValueError, match=r"NeuralGafferInsert: `at_x` / `at_y` / `height`"):
        insert(*args[:6], 5000.0, *args[7:], "transfer", 0, 0, -1.0, mask=mask)


def test_example_workflow_runs_and_matches_the_cli(
    workflow_runner: Any, photo_path: Path, cli_relit: np.ndarray, tmp_path: Path
) -> None:
    """workflows/relight.json (API format), run by the test runner over our nodes and stand-ins of
    LoadImage / SaveImage / PreviewImage, saves what `gaffer-diffusion relight` writes for the same
    photo, map, camera and seed."""
    prompt = json.loads((PACK / "workflows" / "relight.json").read_text())
    relight = prompt["4"]["inputs"]
    assert (relight["azimuth"], relight["elevation"], relight["seed"]) == (AZIMUTH, ELEVATION, SEED)
    shutil.copy(photo_path, tmp_path / "gaffer_example.png")  # what README asks users to copy
    results, saved = workflow_runner(prompt, tmp_path)
    images = dict(saved)["neural_gaffer_relit"]
    assert torch.equal(images, results["4"][0]) and images.shape == (1, 128, 128, 3)
    assert int(np.abs(_levels(images[0]) - cli_relit).max()) <= 1
    assert dict(saved)["preview"].shape == (1, 256, 512, 3)  # the map's tone-mapped preview
