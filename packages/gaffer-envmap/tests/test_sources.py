"""Lighting sources as entry points: a plugin distribution written on the fly (a
`*.dist-info` with `entry_points.txt` on sys.path, as `importlib.metadata` finds an installed one)
is listed, loaded, called with its options and checked, end to end through `gaffer-envmap`'s main()."""

import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from gaffer_envmap.cli import main
from gaffer_envmap.environment_map import EnvironmentMap
from gaffer_envmap.errors import EnvmapSourceError
from gaffer_envmap.io import read_envmap
from gaffer_envmap.sources import (
    ENTRY_POINT_GROUP,
    EnvmapSource,
    envmap_from_photo,
    envmap_from_text,
    envmap_sources,
    load_envmap_source,
    parse_source_options,
    validate_source_map,
)
from gaffer_envmap.stats import total_power
from gaffer_envmap.testing import write_plugin_distribution

MODULE = "gaffer_test_light_plugin"

PLUGIN = textwrap.dedent(
    '''
    """A stand-in for a text-to-HDR model: its "weights" are a file holding one radiance value."""
    import numpy as np
    from pathlib import Path

    from gaffer_envmap.sources import EnvmapSource

    CALLS = []


    def _text(text, *, width, options):
        CALLS.append(("text", text, width, dict(options)))
        value = float(Path(options["weights"]).read_text()) if "weights" in options else 1.0
        return np.full((16, 32, 3), value, np.float32)  # its native size: gaffer resamples it


    def _photo(rgb_srgb, *, fov_deg, width, options):
        CALLS.append(("photo", rgb_srgb.shape, fov_deg, width))
        mean = rgb_srgb.reshape(-1, 3).mean(0)
        return np.broadcast_to(mean, (width // 2, width, 3)).astype(np.float32)


    MODEL = EnvmapSource(name="toy-model", description="a toy", from_text=_text, options=("weights",))
    ESTIMATOR = EnvmapSource(name="toy-estimator", from_photo=_photo)


    def make_nan():
        def text(text, *, width, options):
            out = np.ones((width // 2, width, 3), np.float32)
            out[0, 0, 0] = np.nan
            out[1, 1, 1] = -5.0
            return out
        return EnvmapSource(name="nan-maker", from_text=text)


    SQUARE = EnvmapSource(
        name="square", from_text=lambda text, *, width, options: np.ones((8, 8, 3), np.float32)
    )
    CRASH = EnvmapSource(
        name="crash", from_text=lambda text, *, width, options: 1 / 0
    )
    NOT_A_SOURCE = 42
    '''
)

ENTRY_POINTS = {
    "toy-model": f"{MODULE}:MODEL",
    "toy-estimator": f"{MODULE}:ESTIMATOR",
    "nan-maker": f"{MODULE}:make_nan",
    "square": f"{MODULE}:SQUARE",
    "crash": f"{MODULE}:CRASH",
    "not-a-source": f"{MODULE}:NOT_A_SOURCE",
    "misnamed": f"{MODULE}:MODEL",
    "broken": "gaffer_no_such_module_xyz:SOURCE",
}


@pytest.fixture
def plugin(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """The plugin distribution on sys.path; yields its module (for its CALLS)."""
    site = tmp_path / "site"
    write_plugin_distribution(
        site, name="gaffer-toy-plugin", entry_points=ENTRY_POINTS, modules={MODULE: PLUGIN}
    )
    monkeypatch.delitem(sys.modules, MODULE, raising=False)
    monkeypatch.syspath_prepend(str(site))
    import importlib

    module = importlib.import_module(MODULE)
    yield module
    sys.modules.pop(MODULE, None)


def _one_error_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1, err
    return err[0]


def test_sky_is_registered_through_the_entry_point() -> None:
    entries = {e.name: e for e in envmap_sources()}
    assert "sky" in entries, "reinstall gaffer-envmap (pip install -e packages/gaffer-envmap)"
    assert entries["sky"].target == "gaffer_envmap.builtin_sources:SKY"
    assert entries["sky"].source is not None and entries["sky"].source.capabilities == ("text",)


def test_listing_reports_broken_plugins_without_crashing(plugin, capsys) -> None:
    entries = {e.name: e for e in envmap_sources()}
    assert entries["toy-model"].source is not None
    assert entries["toy-model"].distribution == "gaffer-toy-plugin 1.0"
    assert "ModuleNotFoundError" in (entries["broken"].error or "")
    assert "not a gaffer_envmap.sources.EnvmapSource" in (entries["not-a-source"].error or "")
    assert "registered as 'misnamed'" in (entries["misnamed"].error or "")
    assert entries["nan-maker"].source is not None  # a factory is called
    assert main(["sources"]) == 0
    out = capsys.readouterr().out
    assert "toy-model (text) - a toy; options: weights [gaffer-toy-plugin 1.0]" in out
    assert "broken: failed to load (ModuleNotFoundError" in out
    assert "sky (text)" in out
    with pytest.raises(SystemExit) as exit_:
        main(["sky", "--list-sources"])  # no --out needed
    assert exit_.value.code == 0
    assert "toy-estimator (photo)" in capsys.readouterr().out


def test_cli_sky_runs_a_plugin_with_its_weights_path(plugin, tmp_path, capsys) -> None:
    weights = tmp_path / "weights.txt"
    weights.write_text("2.5")
    out = tmp_path / "out" / "toy.exr"
    argv = ["sky", "--source", "toy-model", "--text", "a dusty red dusk", "--width", "64"]
    rc = main([*argv, "--source-option", f"weights={weights}", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    assert plugin.CALLS == [("text", "a dusty red dusk", 64, {"weights": str(weights)})]
    env = read_envmap(out)
    assert env.radiance_linear.shape == (32, 64, 3)
    np.testing.assert_allclose(env.radiance_linear, 2.5, rtol=1e-5)  # resampled, power kept
    printed = capsys.readouterr().out
    assert "resampled from 32x16" in printed and "source toy-model" in printed


def test_source_sky_equals_the_built_in_text_path(tmp_path, capsys) -> None:
    a, b = tmp_path / "a.exr", tmp_path / "b.exr"
    text = "hazy golden hour, warm, from the left"
    assert main(["sky", "--text", text, "--width", "64", "--out", str(a)]) == 0
    assert main(["sky", "--text", text, "--width", "64", "--source", "sky", "--out", str(b)]) == 0
    np.testing.assert_array_equal(read_envmap(a).radiance_linear, read_envmap(b).radiance_linear)
    studio = tmp_path / "studio.exr"
    argv = ["sky", "--text", "softbox from the left", "--source", "sky", "--width", "32"]
    assert main([*argv, "--source-option", "exposure=0", "--out", str(studio)]) == 0


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--source", "nope", "--text", "x"], "installed: broken, crash, misnamed"),
        (["--source", "broken", "--text", "x"], "failed to load: ModuleNotFoundError"),
        (["--source", "nan-maker", "--text", "x"], "1 NaN, 0 +Inf, 0 -Inf, 1 negative"),
        (["--source", "square", "--text", "x"], "shape (8, 8, 3); expected [He, 2*He, 3]"),
        (["--source", "crash", "--text", "x"], "source 'crash' failed (text): ZeroDivisionError"),
        (["--source", "toy-estimator", "--text", "x"], "from a photo, not from words"),
        (["--source", "toy-model"], "needs `--text PHRASE`"),
        (["--source", "toy-model", "--text", "x", "--source-option", "w"], "is not KEY=VALUE"),
        (["--source", "toy-model", "--text", "x", "--source-option", "seed=1"], "takes weights"),
        (["--source", "toy-model", "--text", "x", "--turbidity", "4"], "`--turbidity` applies"),
        (["--source", "sky", "--text", "x", "--strict"], "`--strict` applies"),
        (["--text", "noon", "--source-option", "a=b"], "`--source-option` goes with `--source"),
        (["--source", "sky", "--text", "noon fluffy", "--source-option", "strict=1"], "'fluffy'"),
    ],
)
def test_cli_sky_source_refusals(plugin, tmp_path, capsys, argv, words) -> None:
    out = tmp_path / "o.exr"
    assert main(["sky", *argv, "--width", "16", "--out", str(out)]) == 2
    line = _one_error_line(capsys)
    assert line.startswith("gaffer-envmap sky: error:") and words in line, line
    assert not out.exists()


def test_from_photo_and_width() -> None:
    calls = []

    def photo(rgb_srgb, *, fov_deg, width, options):
        calls.append((rgb_srgb.dtype, fov_deg, width))
        return EnvironmentMap(radiance_linear=np.ones((width // 2, width, 3), np.float32))

    src = EnvmapSource(name="est", from_photo=photo)
    env = envmap_from_photo(src, np.zeros((6, 8, 3), np.uint8), fov_deg=40, width=32)
    assert env.width == 32 and calls == [(np.float32, 40.0, 32)]
    with pytest.raises(EnvmapSourceError, match="cannot start from words"):
        envmap_from_text(src, "noon", width=32)
    with pytest.raises(EnvmapSourceError, match="even integer"):
        envmap_from_photo(src, np.zeros((6, 8, 3)), fov_deg=40, width=33)


def test_validate_source_map() -> None:
    rng = np.random.default_rng(0)
    env = EnvironmentMap(radiance_linear=rng.random((16, 32, 3), np.float32), convention="threejs")
    out = validate_source_map(env, source="s", width=64)
    assert out.convention == "blender" and out.width == 64
    np.testing.assert_allclose(total_power(out), total_power(env), rtol=1e-5)
    assert "converted from the threejs convention" in out.metadata["gaffer:source_note"]
    bad = np.ones((4, 8, 3), np.float32)
    bad[0, 0] = np.inf
    with pytest.raises(EnvmapSourceError, match=r"0 NaN, 3 \+Inf"):
        validate_source_map(bad, source="s", width=8)
    fixed = validate_source_map(bad, source="s", width=8, policy="zero")
    assert float(fixed.radiance_linear[0, 0, 0]) == 0.0
    for wrong, words in (("a map", "returned a str"), (np.ones((4, 8, 3), bool), "bool array")):
        with pytest.raises(EnvmapSourceError, match=words):
            validate_source_map(wrong, source="s", width=8)


def _ones(text: str, *, width: int, options: object) -> np.ndarray:
    return np.ones((width // 2, width, 3), np.float32)


def test_source_definition_errors() -> None:
    with pytest.raises(EnvmapSourceError, match="neither `from_text` nor `from_photo`"):
        EnvmapSource(name="empty")
    with pytest.raises(EnvmapSourceError, match="is not a source name"):
        EnvmapSource(name="Has Space", from_text=_ones)
    # the tests' type hook (a TypeError) or, without it, the dataclass's own check
    with pytest.raises((EnvmapSourceError, TypeError), match=r"not a callable|nope"):
        EnvmapSource(name="x", from_text="nope")  # type: ignore[arg-type]
    src = EnvmapSource(name="x", from_text=_ones, options=("weights",))
    assert parse_source_options(None, src) == {}
    with pytest.raises(EnvmapSourceError, match="takes weights"):
        parse_source_options(["steps=4"], src)
    assert ENTRY_POINT_GROUP == "gaffer.envmap_sources"


def test_unknown_sky_hints_at_reinstalling(monkeypatch) -> None:
    import gaffer_envmap.sources as sources

    monkeypatch.setattr(sources, "_entry_points", dict)
    with pytest.raises(EnvmapSourceError, match=r"installed: none.*reinstall it"):
        load_envmap_source("sky")


def test_the_tutorial_plugin_works_as_written(tmp_path, monkeypatch, capsys) -> None:
    """docs/tutorials/skies.md, "Plug in your own lighting source": its plugin module, registered as
    its pyproject.toml says, runs through the CLI with its weights file."""
    import re

    doc = Path(__file__).parents[3] / "docs" / "tutorials" / "skies.md"
    if not doc.exists():
        pytest.skip("docs/ is not beside this package")
    text = doc.read_text()
    section = text[text.index("## 5. Plug in your own lighting source") :]
    module = re.findall(r"```python\n(.*?)```", section, re.S)[0]
    entry = dict(re.findall(r'^(my-[\w-]+) = "([\w:]+)"$', section, re.M))
    assert entry == {"my-text2hdr": "my_light:TEXT2HDR", "my-estimator": "my_light:ESTIMATOR"}
    site = tmp_path / "site"
    write_plugin_distribution(
        site, name="my-light", entry_points=entry, modules={"my_light": module}
    )
    monkeypatch.delitem(sys.modules, "my_light", raising=False)
    monkeypatch.syspath_prepend(str(site))
    weights = tmp_path / "model.npz"
    np.savez(weights, sky=np.array([0.8, 0.9, 1.2]), ground=np.array([0.2, 0.2, 0.2]))
    out = tmp_path / "sunset.exr"
    argv = ["sky", "--source", "my-text2hdr", "--text", "a warm sunset", "--width", "64"]
    assert main([*argv, "--source-option", f"weights={weights}", "--out", str(out)]) == 0
    env = read_envmap(out)
    assert env.metadata.get("gaffer:source") == "my-text2hdr"
    assert env.radiance_linear[0].mean() > env.radiance_linear[-1].mean() > 0
    estimator = load_envmap_source("my-estimator")
    photo = np.full((12, 16, 3), 0.5, np.float32)
    lit = envmap_from_photo(
        estimator, photo, fov_deg=50, width=32, options={"weights": str(weights)}
    )
    assert lit.radiance_linear.shape == (16, 32, 3)
    sys.modules.pop("my_light", None)


def test_a_name_registered_by_two_distributions_is_reported(plugin, tmp_path, monkeypatch) -> None:
    other = tmp_path / "other"
    write_plugin_distribution(
        other, name="gaffer-other-plugin", entry_points={"toy-model": f"{MODULE}:ESTIMATOR"}
    )
    monkeypatch.syspath_prepend(str(other))
    entry = {e.name: e for e in envmap_sources()}["toy-model"]
    assert entry.source is None and "registered more than once" in (entry.error or "")
    assert "gaffer-other-plugin 1.0" in (entry.error or "")
    with pytest.raises(EnvmapSourceError, match="registered more than once"):
        load_envmap_source("toy-model")
