"""`gaffer-diffusion insert --light-source NAME`: a lighting source plugin (entry
point group `gaffer.envmap_sources`) makes the lighting, from the background photo (a light estimator)
or from `--light-text` (a text-to-HDR model, or the built-in "sky"). The plugin is a distribution
written on the fly (`gaffer_envmap.testing.write_plugin_distribution`), found by importlib.metadata as
an installed one, and run end to end through the CLI's main()."""

import importlib
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from gaffer_diffusion import insert as ins
from gaffer_diffusion import pretrained
from gaffer_diffusion.cli import main
from gaffer_diffusion.photo import envmap_backdrop
from gaffer_envmap.bundled import read_bundled_hdri
from gaffer_envmap.io import read_envmap
from gaffer_envmap.sources import envmap_from_text, load_envmap_source
from gaffer_envmap.testing import write_plugin_distribution

W, H = 160, 120
OBJECT = pretrained.example_dataset_path() / "objects" / "procedural_002" / "lit" / "000_000.png"
MODULE = "gaffer_test_insert_light_plugin"
PLUGIN = textwrap.dedent(
    """
    import numpy as np
    from gaffer_envmap.sources import EnvmapSource

    CALLS = []


    def _estimate(rgb_srgb, *, fov_deg, width, options):
        CALLS.append((rgb_srgb.shape, rgb_srgb.dtype.name, fov_deg, width, dict(options)))
        gain = float(options.get("gain", "1"))
        mean = (rgb_srgb.reshape(-1, 3).mean(0) ** 2.2) * gain
        out = np.broadcast_to(mean, (width // 2, width, 3)).copy()
        out[: width // 8] *= 4.0  # a bright sky band
        return out.astype(np.float32)


    def _nan(rgb_srgb, *, fov_deg, width, options):
        return np.full((width // 2, width, 3), np.nan, np.float32)


    ESTIMATOR = EnvmapSource(name="toy-estimator", from_photo=_estimate, options=("gain",))
    NAN = EnvmapSource(name="nan-estimator", from_photo=_nan)
    """
)


@pytest.fixture
def plugin(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    site = tmp_path / "site"
    write_plugin_distribution(
        site,
        name="gaffer-toy-estimator",
        entry_points={"toy-estimator": f"{MODULE}:ESTIMATOR", "nan-estimator": f"{MODULE}:NAN"},
        modules={MODULE: PLUGIN},
    )
    monkeypatch.delitem(sys.modules, MODULE, raising=False)
    monkeypatch.syspath_prepend(str(site))
    yield importlib.import_module(MODULE)
    sys.modules.pop(MODULE, None)


@pytest.fixture(scope="module")
def background(tmp_path_factory) -> Path:
    env = read_bundled_hdri("courtyard")
    view = envmap_backdrop(env.radiance_linear, ins.LEVEL_CAMERA.rotation, height=H, width=W)
    path = tmp_path_factory.mktemp("bg") / "bg.png"
    Image.fromarray(np.round(view * 255).astype(np.uint8)).save(path)
    return path


def _run(background: Path, out: Path, *extra: str) -> int:
    return main(["insert", str(OBJECT), "--into", str(background), "--out", str(out), *extra])


COMMON = ("--at", "80,100", "--height", "50", "--shadow", "none")


def test_a_light_estimator_plugin_lights_the_insert(plugin, background, tmp_path, capsys) -> None:
    out, saved = tmp_path / "o.png", tmp_path / "light.exr"
    flags = ["--light-source", "toy-estimator", "--light-source-option", "gain=2"]
    assert _run(background, out, *COMMON, *flags, "--save-envmap", str(saved)) == 0
    assert plugin.CALLS == [((H, W, 3), "float32", 39.6, 256, {"gain": "2"})]
    assert "lighting: --light-source toy-estimator from the background photo" in (
        capsys.readouterr().out
    )
    env = read_envmap(saved)
    assert env.radiance_linear.shape == (128, 256, 3)
    assert env.radiance_linear[0].mean() == pytest.approx(4 * env.radiance_linear[-1].mean())
    # the saved map is the lighting used: the same picture under --envmap
    again = tmp_path / "again.png"
    assert _run(background, again, *COMMON, "--envmap", str(saved)) == 0
    assert np.array_equal(np.asarray(Image.open(out)), np.asarray(Image.open(again)))


def test_the_built_in_sky_source_from_words(background, tmp_path) -> None:
    saved = tmp_path / "sky.exr"
    text = "golden hour from the left"
    flags = ["--light-source", "sky", "--light-text", text, "--save-envmap", str(saved)]
    assert _run(background, tmp_path / "o.png", *COMMON, *flags) == 0
    want = envmap_from_text(load_envmap_source("sky"), text, width=256)
    np.testing.assert_array_equal(read_envmap(saved).radiance_linear, want.radiance_linear)


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--light-source", "nope"], "installed: nan-estimator, sky, toy-estimator"),
        (["--light-text", "noon"], "`--light-text` goes with `--light-source NAME`"),
        (["--light-source-option", "a=b"], "`--light-source-option` goes with"),
        (["--light-source", "sky"], "pass `--light-text PHRASE`"),
        (["--light-source", "toy-estimator", "--light-text", "noon"], "drop `--light-text`"),
        (["--light-source", "toy-estimator", "--envmap", "city"], "drop `--envmap`"),
        (["--light-source", "toy-estimator", "--light-from-photo"], "drop `--light-from-photo`"),
        (["--light-source", "toy-estimator", "--key-light", "90,30"], "drop `--key-light`"),
        (["--light-source", "toy-estimator", "--w2c", "w2c.npy"], "`--w2c`"),
        (["--light-source", "toy-estimator", "--light-source-option", "x=1"], "takes gain"),
        (["--light-source", "nan-estimator"], "98304 NaN"),
    ],
)
def test_light_source_refusals_are_one_line_before_the_model_loads(
    plugin, background, tmp_path, monkeypatch, capsys, extra, words
) -> None:
    import gaffer_diffusion.cli.insert as cli_insert

    def no_model(*_a: object) -> None:
        raise AssertionError("the model was loaded")

    monkeypatch.setattr(cli_insert, "_load_model", no_model)
    work = tmp_path / "work"
    work.mkdir()
    np.save(tmp_path / "w2c.npy", np.eye(4)[:3])
    extra = [str(tmp_path / a) if a == "w2c.npy" else a for a in extra]
    monkeypatch.chdir(work)
    assert _run(background, work / "o.png", *extra) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
    assert sorted(p.name for p in work.iterdir()) == []  # nothing written
