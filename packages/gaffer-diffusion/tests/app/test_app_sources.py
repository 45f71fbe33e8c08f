"""The app's lighting from words: a lighting source (the built-in "sky" or a plugin of
the entry-point group `gaffer.envmap_sources`) turns the words into the map the page previews and
relights under. The engine is tested in-process with a plugin written on the fly; the page through
its API, with the built-in source (the server is another process)."""

import sys
import textwrap
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from gaffer_diffusion.app.config import config_from_args
from gaffer_diffusion.app.engine import SOURCE_MAP_WIDTH, Engine
from gaffer_diffusion.cli.parser import _parser
from gaffer_diffusion.errors import InputValueError
from gaffer_envmap.errors import EnvmapSourceError
from gaffer_envmap.io import read_envmap
from gaffer_envmap.sources import envmap_from_text, load_envmap_source
from gaffer_envmap.testing import write_plugin_distribution

MODULE = "gaffer_test_app_light_plugin"
PLUGIN = textwrap.dedent(
    """
    import numpy as np
    from gaffer_envmap.sources import EnvmapSource

    CALLS = []


    def _text(text, *, width, options):
        CALLS.append((text, width))
        return np.full((width // 2, width, 3), 0.5, np.float32)


    def _photo(rgb_srgb, *, fov_deg, width, options):
        return np.ones((width // 2, width, 3), np.float32)


    WORDS = EnvmapSource(name="toy-words", from_text=_text)
    PHOTO = EnvmapSource(name="toy-photo", from_photo=_photo)
    """
)


@pytest.fixture
def engine(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    site = tmp_path / "site"
    write_plugin_distribution(
        site,
        name="gaffer-toy-app-plugin",
        entry_points={"toy-words": f"{MODULE}:WORDS", "toy-photo": f"{MODULE}:PHOTO"},
        modules={MODULE: PLUGIN},
    )
    monkeypatch.delitem(sys.modules, MODULE, raising=False)
    monkeypatch.syspath_prepend(str(site))
    yield Engine(config_from_args(_parser().parse_args(["app"])))
    sys.modules.pop(MODULE, None)


def test_the_page_offers_the_sources_that_take_words(engine: Engine) -> None:
    names = engine.text_sources()
    assert "sky" in names and "toy-words" in names and "toy-photo" not in names


def test_a_source_map_is_made_once_and_read_like_an_upload(engine: Engine, tmp_path) -> None:
    plugin = sys.modules.get(MODULE) or __import__(MODULE)
    folder = tmp_path / "maps"
    first = engine.source_envmap_path("toy-words", "  a  grey day ", folder)
    again = engine.source_envmap_path("toy-words", "a grey day", folder)
    assert first == again and plugin.CALLS == [("a grey day", SOURCE_MAP_WIDTH)]
    env = engine.envmap(first)
    assert env.radiance_linear.shape == (SOURCE_MAP_WIDTH // 2, SOURCE_MAP_WIDTH, 3)
    sky = engine.source_envmap_path("sky", "golden hour from the left", folder)
    want = envmap_from_text(load_envmap_source("sky"), "golden hour from the left", width=512)
    np.testing.assert_array_equal(read_envmap(sky).radiance_linear, want.radiance_linear)


@pytest.mark.parametrize(
    ("source", "words", "error", "match"),
    [
        ("sky", "   ", InputValueError, "type the words"),
        ("nope", "noon", EnvmapSourceError, "installed: sky, toy-photo, toy-words"),
        ("toy-photo", "noon", EnvmapSourceError, "cannot start from words"),
    ],
)
def test_source_refusals(engine: Engine, tmp_path, source, words, error, match) -> None:
    with pytest.raises(error, match=match):
        engine.source_envmap_path(source, words, tmp_path / "maps")
    assert not (tmp_path / "maps").exists() or not any((tmp_path / "maps").iterdir())


@pytest.fixture(scope="module")
def client(app_server: Any, tmp_path_factory: pytest.TempPathFactory) -> Any:
    from gradio_client import Client

    return Client(
        app_server.url, verbose=False, download_files=str(tmp_path_factory.mktemp("downloads"))
    )


@pytest.mark.slow
def test_the_page_previews_the_words_of_the_sky_source(client: Any) -> None:
    import torch

    from gaffer_diffusion import pretrained
    from gaffer_diffusion.conditioning import lighting_from_envmap
    from gaffer_envmap.poses import orbit_w2c_blender

    tiny, pose = "gaffer-tiny (shipped)", (30.0, 10.0, 0.0)
    text = "golden hour from the left"
    ldr, _, _ = client.predict(tiny, "sunset", None, *pose, "sky", text, api_name="/preview")
    with Image.open(ldr) as im:
        got = np.asarray(im.convert("RGB")).astype(int)
    env = envmap_from_text(load_envmap_source("sky"), text, width=SOURCE_MAP_WIDTH)
    maps = lighting_from_envmap(
        env,
        [orbit_w2c_blender(pose[0], pose[1])],
        size=128,
        compat=pretrained.gaffer_tiny_sampling().compat,  # gaffer-tiny's, from its manifest
    )
    want = (maps.ldr[0].permute(1, 2, 0) * 255).round().to(torch.uint8).numpy().astype(int)
    assert np.abs(got - want).max() <= 1
    from gradio_client.exceptions import AppError

    with pytest.raises(AppError, match="type the words"):
        client.predict(tiny, "sunset", None, *pose, "sky", "", api_name="/preview")
