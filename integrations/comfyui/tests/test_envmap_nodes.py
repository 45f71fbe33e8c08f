"""LoadEnvmap, RotateEnvmap and Sky: linear float32 maps in and out, previews apart, one-line refusals."""

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
import torch


@pytest.fixture(scope="module")
def small_map(lib: ModuleType) -> object:
    """The bundled 'sunset' shrunk power-exactly to 32 x 64 (fast rotations)."""
    from gaffer_envmap.bundled import read_bundled_hdri
    from gaffer_envmap.resample import resize_conservative

    return lib.GafferEnvmap(envmap=resize_conservative(read_bundled_hdri("sunset"), 32), label="s")


def test_load_bundled_and_file_keeps_linear_float32(
    nodes: dict[str, type], lib: ModuleType, tmp_path: Path
) -> None:
    from gaffer_envmap.bundled import read_bundled_hdri
    from gaffer_envmap.io import write_envmap

    env, preview = nodes["NeuralGafferLoadEnvmap"]().load("courtyard", "raise")
    assert isinstance(env, lib.GafferEnvmap) and env.label == "courtyard"
    rad = env.radiance_linear
    assert rad.dtype == np.float32 and rad.shape == (512, 1024, 3)
    assert rad.max() > 1.0  # HDR: not clipped
    assert np.array_equal(rad, read_bundled_hdri("courtyard").radiance_linear)
    assert preview.shape == (1, 256, 512, 3) and preview.dtype == torch.float32
    assert 0.0 <= float(preview.min()) and float(preview.max()) <= 1.0
    sun = np.zeros((8, 16, 3), np.float32)
    sun[2, 5] = 5000.0
    write_envmap(tmp_path / "sun.exr", sun)
    env, preview = nodes["NeuralGafferLoadEnvmap"]().load(str(tmp_path / "sun.exr"), "raise")
    assert env.label == "sun.exr" and float(env.radiance_linear.max()) == 5000.0
    assert preview.shape == (1, 8, 16, 3)
    changed = nodes["NeuralGafferLoadEnvmap"].IS_CHANGED
    before = changed(str(tmp_path / "sun.exr"), "raise")
    sun[2, 6] = 1.0
    write_envmap(tmp_path / "sun.exr", sun)
    assert changed(str(tmp_path / "sun.exr"), "raise") != before  # an edited file is read again
    assert changed("no-such-map", "raise") == "no-such-map|raise"


def test_load_refusals_name_the_input(
    nodes: dict[str, type], lib: ModuleType, tmp_path: Path
) -> None:
    load = nodes["NeuralGafferLoadEnvmap"]().load
    (tmp_path / "map.png").write_bytes(b"")
    (tmp_path / "broken.exr").write_text("not an EXR\n")
    for value, words in (
        ("", "`envmap` is empty"),
        ("no-such-hdri", "neither a bundled HDRI"),
        (str(tmp_path / "map.png"), "give an HDR map (.exr or .hdr)"),
        (str(tmp_path / "broken.exr"), "NeuralGafferLoadEnvmap: `envmap` broken.exr"),
    ):
        with pytest.raises(ValueError, match="NeuralGafferLoadEnvmap") as info:
            load(value, "raise")
        assert words in str(info.value) and "\n" not in str(info.value)
        assert isinstance(info.value, lib.NodeInputError)
    with pytest.raises(ValueError, match="`sanitize` is 'nope'"):
        load("courtyard", "nope")


def test_sanitize_policy_reaches_the_reader(nodes: dict[str, type], tmp_path: Path) -> None:
    import OpenEXR

    bad = np.ones((8, 16, 3), np.float32)
    bad[1, 1] = np.nan
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, {"RGB": bad}).write(
        str(tmp_path / "n.exr")
    )
    load = nodes["NeuralGafferLoadEnvmap"]().load
    with pytest.raises(ValueError, match="set `sanitize` to 'zero' or 'clamp'"):
        load(str(tmp_path / "n.exr"), "raise")
    env, _ = load(str(tmp_path / "n.exr"), "zero")
    assert np.isfinite(env.radiance_linear).all() and env.radiance_linear[1, 1].sum() == 0


def test_rotate_by_azimuth_is_the_turntable_spin(nodes: dict[str, type], small_map: object) -> None:
    """Azimuth alone turns the light about world up exactly as `lighting_from_envmap`'s `spin_deg`
    (a quarter turn is a permutation of columns, so the encodings agree to float round-off)."""
    from gaffer_diffusion.conditioning import lighting_from_envmap
    from gaffer_envmap.poses import orbit_w2c_blender

    rotate = nodes["NeuralGafferRotateEnvmap"]().rotate
    turned, preview = rotate(small_map, 90.0, 0.0, 0.0)
    assert preview.shape == (1, 32, 64, 3) and turned.radiance_linear.dtype == np.float32
    pose = orbit_w2c_blender(30.0, 10.0)
    a = lighting_from_envmap(turned.envmap, [pose], size=32, compat="default")
    b = lighting_from_envmap(small_map.envmap, [pose], size=32, compat="default", spin_deg=90.0)
    assert float((a.hdr - b.hdr).abs().max()) < 1e-4 and float((a.ldr - b.ldr).abs().max()) < 1e-4
    same, _ = rotate(small_map, 360.0, 0.0, 0.0)
    assert same is small_map  # a whole turn: the map itself, not a resampled copy


@pytest.mark.parametrize("angles", [(90.0, 0.0, 0.0), (0.0, 45.0, 0.0), (60.0, 30.0, 90.0)])
def test_rotate_moves_a_light_where_the_angles_say(
    nodes: dict[str, type], lib: ModuleType, angles: tuple[float, float, float]
) -> None:
    """A small bright light at world +x ends at R(azimuth, elevation, spin) +x (one texel of 64 x 128),
    and the rotation keeps the map's power (the conservative filter)."""
    from gaffer_envmap import EnvironmentMap
    from gaffer_envmap.conventions import direction_to_uv, uv_to_direction
    from gaffer_envmap.stats import total_power

    he = 64
    rad = np.full((he, 2 * he, 3), 0.01, np.float32)
    u, v = direction_to_uv(np.array([[1.0, 0.0, 0.0]]), "blender")
    rad[int(v[0] * he), int(u[0] * 2 * he) % (2 * he)] = 1000.0
    env = lib.GafferEnvmap(envmap=EnvironmentMap(radiance_linear=rad), label="dot")
    out, _ = nodes["NeuralGafferRotateEnvmap"]().rotate(env, *angles)
    lum = out.radiance_linear.sum(-1)
    i, j = np.unravel_index(np.argmax(lum), lum.shape)
    got = uv_to_direction(np.array([(j + 0.5) / (2 * he)]), np.array([(i + 0.5) / he]), "blender")[
        0
    ]
    want = lib.envmap_nodes.world_rotation(*angles) @ np.array([1.0, 0.0, 0.0])
    assert float(np.degrees(np.arccos(np.clip(got @ want, -1, 1)))) < 4.0
    assert np.allclose(total_power(out.envmap), total_power(env.envmap), rtol=1e-3)


def test_rotate_refusals(nodes: dict[str, type], small_map: object) -> None:
    rotate = nodes["NeuralGafferRotateEnvmap"]().rotate
    with pytest.raises(ValueError, match=r"`elevation` is 120.0; pass a number in \[-90, 90\]"):
        rotate(small_map, 0.0, 120.0, 0.0)
    with pytest.raises(ValueError, match="`envmap` is a Tensor; connect a GAFFER_ENVMAP"):
        rotate(torch.ones(1, 8, 16, 3), 10.0, 0.0, 0.0)


def test_sky_is_gaffer_envmap_sky(nodes: dict[str, type], tmp_path: Path) -> None:
    """The Sky node's map equals `gaffer-envmap sky --text PHRASE` (run in-process) to float32."""
    from gaffer_envmap.cli import main
    from gaffer_envmap.io import read_envmap

    phrase = "overcast noon"
    env, preview = nodes["NeuralGafferSky"]().make(phrase, "sky", -3.0, 64, False)
    assert main(["sky", "--text", phrase, "--width", "64", "--out", str(tmp_path / "s.exr")]) == 0
    cli = read_envmap(tmp_path / "s.exr", sanitize="strict")
    assert env.radiance_linear.shape == (32, 64, 3) and preview.shape == (1, 32, 64, 3)
    assert np.allclose(env.radiance_linear, cli.radiance_linear, rtol=1e-6, atol=0)


def test_sky_refusals(nodes: dict[str, type]) -> None:
    make = nodes["NeuralGafferSky"]().make
    with pytest.raises(ValueError, match="`text` is empty"):
        make("  ", "sky", -3.0, 64, False)
    with pytest.raises(ValueError, match="`width` is 63"):
        make("noon", "sky", -3.0, 63, False)
    with pytest.raises(ValueError, match="NeuralGafferSky: `source` 'nope'"):
        make("noon", "nope", -3.0, 64, False)
    with pytest.raises(ValueError, match="NeuralGafferSky: `text` 'noon zorblax'"):
        make("noon zorblax", "sky", -3.0, 64, True)
