"""Physical skies, the ephemeris, the phrase grammar and `gaffer-envmap sky`."""

import importlib.util
import itertools
import math
import sys
from datetime import UTC, datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pytest

from gaffer_envmap import read_envmap
from gaffer_envmap.cli import main
from gaffer_envmap.conventions import direction_grid, direction_to_uv, solid_angle
from gaffer_envmap.errors import MissingDependencyError, ParameterError
from gaffer_envmap.phrase import VOCABULARY, read_phrase
from gaffer_envmap.sky import (
    SUN_ANGULAR_DIAMETER_DEG,
    SkyConfig,
    SunPosition,
    cie_overcast_sky,
    preetham_sky,
    sky_envmap,
    sun_direction,
    sun_radiance,
)
from gaffer_envmap.studio import StudioConfig, default_light, light_irradiance, studio_envmap
from gaffer_envmap.sun_position import parse_place, parse_time, sun_position_at

LUMA = np.array([0.2126, 0.7152, 0.0722])
SUN_OMEGA = 2 * math.pi * (1 - math.cos(math.radians(SUN_ANGULAR_DIAMETER_DEG / 2)))


def _sky(el: float, az: float, width: int = 128, **kw) -> np.ndarray:
    cfg = SkyConfig(sun=SunPosition(elevation_deg=el, azimuth_deg=az), **kw)
    return sky_envmap(cfg, width).radiance_linear.astype(np.float64)


def _power(radiance: np.ndarray) -> np.ndarray:
    h, w = radiance.shape[:2]
    return (radiance * solid_angle(h, w)[..., None]).sum(axis=(0, 1))


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(
        math.acos(float(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))
    )


# --------------------------------------------------------------------------- convention and sun


def test_azimuth_follows_blenders_sun_rotation_in_the_blender_lat_long() -> None:
    # sun_rotation 0 points at world +y, 90 degrees at +x, z up
    np.testing.assert_allclose(sun_direction(0, 0), [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(sun_direction(0, 90), [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(sun_direction(0, 180), [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(sun_direction(90, 33), [0, 0, 1], atol=1e-12)
    # in the Blender lat-long: +y at u = 0.25, +x at the centre column, -x on the seam
    assert direction_to_uv(sun_direction(0, 0))[0] == pytest.approx(0.25)
    assert direction_to_uv(sun_direction(0, 90))[0] == pytest.approx(0.5)
    assert direction_to_uv(sun_direction(0, 270))[0] % 1.0 == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize(
    ("elevation", "azimuth"),
    [(30, 0), (30, 90), (10, 180), (45, 270), (70, 37), (5, 123), (60, 311)],
)
def test_brightest_pixel_is_the_sun_at_the_requested_direction(
    elevation: float, azimuth: float
) -> None:
    width = 256
    env = _sky(elevation, azimuth, width)
    lum = env @ LUMA
    i, j = np.unravel_index(int(np.argmax(lum)), lum.shape)
    pixel_dir = direction_grid(width // 2, width)[i, j]
    # within the pixel the disc falls in: half a pixel diagonal (360/256 deg a side)
    assert _angle_deg(pixel_dir, sun_direction(elevation, azimuth)) < 0.75 * 360 / width * 1.5
    # and it is the pixel direction_to_uv names (or its neighbour, for a sun on a pixel border)
    u, v = direction_to_uv(sun_direction(elevation, azimuth))
    du = ((j + 0.5) / width - float(u) + 0.5) % 1.0 - 0.5
    assert abs(du) <= 1.0 / width and abs((i + 0.5) / (width // 2) - float(v)) <= 2.0 / width


@pytest.mark.parametrize("width", [16, 64, 512])
@pytest.mark.parametrize("elevation", [2.0, 40.0])
def test_sun_power_is_kept_when_the_disc_is_sub_pixel(width: int, elevation: float) -> None:
    with_disc = _sky(elevation, 200, width)
    without = _sky(elevation, 200, width, sun_disc=False)
    expected = sun_radiance(elevation, 3.0) * SUN_OMEGA * 2.0**-3  # default exposure -3 EV
    np.testing.assert_allclose(_power(with_disc - without), expected, rtol=2e-5)


def test_direct_sun_is_plausible_at_noon() -> None:
    # clear day, sun at 60 degrees: direct normal illuminance 80-110 klx
    direct = float(sun_radiance(60.0, 3.0) @ LUMA) * SUN_OMEGA
    assert 80.0 < direct < 110.0
    # and redder and much dimmer near the horizon
    low = sun_radiance(2.0, 3.0)
    assert float(low @ LUMA) * SUN_OMEGA < 0.2 * direct
    assert low[0] / low[2] > 3 * sun_radiance(60.0, 3.0)[0] / sun_radiance(60.0, 3.0)[2]
    assert not sun_radiance(-1.0, 3.0).any()


def test_sky_is_brighter_near_the_sun() -> None:
    sun = sun_direction(30, 90)
    near = preetham_sky(sun_direction(30, 100), sun, 3.0) @ LUMA
    side = preetham_sky(sun_direction(30, 180), sun, 3.0) @ LUMA
    away = preetham_sky(sun_direction(30, 270), sun, 3.0) @ LUMA
    assert near > 2 * side and side > 0 and away > 0


def test_clear_noon_zenith_is_blue() -> None:
    zenith = preetham_sky(np.array([0.0, 0.0, 1.0]), sun_direction(60, 180), 2.5)
    assert zenith[2] > 1.4 * zenith[0] and zenith[2] > zenith[1]
    env = _sky(60, 180, 64, turbidity=2.5)
    top = env[:4].mean(axis=(0, 1))
    assert top[2] > 1.4 * top[0]


def test_low_sun_makes_a_redder_sky() -> None:
    def red_over_blue(el: float) -> float:
        env = _sky(el, 90, 64, sun_disc=False)
        sky = env[: env.shape[0] // 2].mean(axis=(0, 1))
        return float(sky[0] / sky[2])

    assert red_over_blue(3) > 1.3 * red_over_blue(60)
    # the horizon under the sun is warm at sunset
    horizon = preetham_sky(sun_direction(1, 90), sun_direction(1, 90), 3.0)
    assert horizon[0] > 1.5 * horizon[2]


def test_overcast_is_flatter_than_clear_and_follows_the_cie_law() -> None:
    def spread(env: np.ndarray) -> tuple[float, float]:
        lum = env[: env.shape[0] // 2] @ LUMA  # the sky half
        return float(lum.std() / lum.mean()), float(lum.max() / lum.min())

    clear = spread(_sky(30, 90, 64, sun_disc=False))
    overcast = spread(_sky(30, 90, 64, model="cie-overcast"))
    assert overcast[0] < 0.75 * clear[0]  # coefficient of variation
    assert overcast[1] <= 3.0 < 1.5 * overcast[1] < clear[1]  # brightest over darkest
    # CIE overcast: the zenith is 3 times as bright as the horizon, and no sun is visible
    lz = cie_overcast_sky(np.array([0.0, 0.0, 1.0]), 40)
    lh = cie_overcast_sky(np.array([1.0, 0.0, 0.0]), 40)
    np.testing.assert_allclose(lz, 3 * lh)
    env = _sky(30, 90, 64, model="cie-overcast")
    assert float(env.max()) <= float(env[0].mean()) * 1.001  # the zenith row is the brightest


def test_ground_is_a_lambertian_floor_of_the_given_albedo() -> None:
    dark = _sky(40, 90, 64, ground_albedo=(0.0, 0.0, 0.0))
    light = _sky(40, 90, 64, ground_albedo=(0.4, 0.4, 0.4))
    green = _sky(40, 90, 64, ground_albedo=(0.1, 0.4, 0.1))
    assert not dark[16:].any()
    # L = rho E / pi: the ground holds albedo/pi of the horizontal irradiance of sky and sun
    upper = light.copy()
    upper[16:] = 0
    z = direction_grid(32, 64)[..., 2:3]
    e_h = (upper * np.clip(z, 0, None) * solid_angle(32, 64)[..., None]).sum(axis=(0, 1))
    np.testing.assert_allclose(light[-1, 0], 0.4 * e_h / math.pi, rtol=0.05)
    assert green[-1, 0, 1] > 3 * green[-1, 0, 0]
    np.testing.assert_allclose(light[16:].std(axis=(0, 1)), 0, atol=1e-6)  # uniform floor


def test_sun_below_the_horizon_gives_a_dimmer_bluer_twilight_and_a_dark_night() -> None:
    means = [float((_sky(el, 270, 64) @ LUMA).mean()) for el in (5, 0, -3, -6, -12, -30)]
    assert all(a > b for a, b in itertools.pairwise(means))
    assert means[-1] > 0  # the night floor, finite and positive
    dusk = _sky(-4, 270, 64)
    np.testing.assert_array_equal(dusk, _sky(-4, 270, 64, sun_disc=False))  # no sun disc
    zen = dusk[:4].mean(axis=(0, 1))
    assert zen[2] > 1.5 * zen[0]


def test_exposure_and_tint_scale_the_map() -> None:
    a = _sky(30, 90, 32)
    b = _sky(30, 90, 32, exposure_ev=-2.0)
    np.testing.assert_allclose(b, 2 * a, rtol=1e-6)
    warm = _sky(30, 90, 32, tint_rgb=(1.2, 1.0, 0.8))
    np.testing.assert_allclose(warm[..., 0], 1.2 * a[..., 0], rtol=1e-6)


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"turbidity": 1.0}, "`turbidity`"),
        ({"turbidity": float("nan")}, "`turbidity`"),
        ({"ground_albedo": (1.5, 0.2, 0.2)}, "`ground albedo`"),
        ({"exposure_ev": float("inf")}, "`exposure`"),
    ],
)
def test_bad_sky_parameters_are_refused_by_name(kwargs: dict, words: str) -> None:
    with pytest.raises(ParameterError, match=words):
        SkyConfig(sun=SunPosition(elevation_deg=10, azimuth_deg=0), **kwargs)


def test_bad_sun_and_width_are_refused() -> None:
    with pytest.raises(ParameterError, match="elevation"):
        SunPosition(elevation_deg=95, azimuth_deg=0)
    with pytest.raises(ParameterError, match="azimuth"):
        SunPosition(elevation_deg=5, azimuth_deg=float("nan"))
    cfg = SkyConfig(sun=SunPosition(elevation_deg=10, azimuth_deg=0))
    for width in (7, 33, 0, 40000):
        with pytest.raises(ParameterError, match="`width`"):
            sky_envmap(cfg, width)


# --------------------------------------------------------------------------- studio


def test_studio_lights_sit_where_the_words_put_them_and_keep_their_power() -> None:
    left = default_light("softbox", azimuth_deg=270)
    for width in (32, 256):
        env = studio_envmap(StudioConfig(lights=(left,), wall_luminance=0.0), width)
        rad = env.radiance_linear.astype(np.float64)
        np.testing.assert_allclose(_power(rad) @ LUMA, light_irradiance(left) * 2.0**-3, rtol=1e-5)
        weights = rad @ LUMA * solid_angle(width // 2, width)
        centroid = (direction_grid(width // 2, width) * weights[..., None]).sum(axis=(0, 1))
        assert centroid[0] < -0.8 * np.linalg.norm(centroid)  # from the left: world -x


# --------------------------------------------------------------------------- ephemeris


def test_place_and_time_parsing_refuses_what_it_cannot_place() -> None:
    assert parse_place("-33.87, 151.21") == (-33.87, 151.21)
    for bad in ("48.8", "a,b", "91,0", "0,181", "nan,0"):
        with pytest.raises(ParameterError, match="`--at`"):
            parse_place(bad, "--at")
    assert parse_time("2026-06-21T12:00Z").utcoffset() == timedelta(0)
    with pytest.raises(ParameterError, match="UTC offset"):
        parse_time("2026-06-21T12:00")
    with pytest.raises(ParameterError, match="ISO 8601"):
        parse_time("noonish")


def test_sun_from_the_ephemeris_matches_published_positions() -> None:
    pytest.importorskip("astral")
    # June solstice 2024 at Greenwich, local solar noon (12:02 UTC): elevation 90 - 51.4769 + 23.44
    # = 61.96 degrees due south (NOAA solar calculator: 61.97, azimuth 180.0)
    london = sun_position_at(51.4769, -0.0005, datetime(2024, 6, 21, 12, 2, tzinfo=UTC))
    assert london.elevation_deg == pytest.approx(61.96, abs=1.0)
    assert london.azimuth_deg == pytest.approx(180.0, abs=1.0)
    # the same instant written in another zone is the same sun
    cest = timezone(timedelta(hours=2))
    same = sun_position_at(51.4769, -0.0005, datetime(2024, 6, 21, 14, 2, tzinfo=cest))
    assert same.elevation_deg == pytest.approx(london.elevation_deg, abs=1e-9)
    # Sydney at noon on the same day (its winter): 90 - 33.87 - 23.44 = 32.69 degrees, due north
    sydney = sun_position_at(-33.8688, 151.2093, parse_time("2024-06-21T12:00+10:00"))
    assert sydney.elevation_deg == pytest.approx(32.7, abs=1.0)
    assert min(sydney.azimuth_deg, 360 - sydney.azimuth_deg) < 3.0
    # sunrise in London is in the north-east
    dawn = sun_position_at(51.4769, -0.0005, parse_time("2024-06-21T05:00+01:00"))
    assert -1 < dawn.elevation_deg < 4 and 40 < dawn.azimuth_deg < 65


def test_missing_astral_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "astral", None)
    monkeypatch.setitem(sys.modules, "astral.sun", None)
    with pytest.raises(MissingDependencyError, match=r'pip install "gaffer-envmap\[sky\]"'):
        sun_position_at(0.0, 0.0, datetime(2024, 1, 1, tzinfo=UTC))


# --------------------------------------------------------------------------- phrase grammar


def test_phrase_reads_time_weather_colour_and_direction() -> None:
    r = read_phrase("Hazy golden-hour sky from the left, warm, with fluffy clouds")
    assert (r.sun_elevation_deg, r.sun_azimuth_deg) == (6.0, 270.0)
    assert r.turbidity == 6.0 and r.model == "preetham"
    assert r.tint_rgb is not None and r.tint_rgb[0] > r.tint_rgb[2]
    assert r.unknown == ("fluffy", "clouds")
    assert [w for w, _ in r.understood] == ["hazy", "golden hour", "from the left", "warm"]
    assert "sky" in r.ignored and "with" in r.ignored
    assert not r.is_studio
    cfg = r.scene()
    assert isinstance(cfg, SkyConfig) and cfg.sun.azimuth_deg == 270.0
    assert any("fluffy, clouds" in line for line in r.describe())


@pytest.mark.parametrize(
    ("phrase", "elevation", "azimuth"),
    [
        ("dawn", -4, 90),
        ("sunrise", 1, 90),
        ("morning", 25, 120),
        ("noon", 60, 180),
        ("midday", 60, 180),
        ("afternoon", 35, 240),
        ("sunset", 1, 270),
        ("dusk", -4, 270),
        ("night", -25, 0),
        ("sunset from behind", 1, 0),
        ("noon from the right", 60, 90),
        ("morning, from the front", 25, 180),
        ("from the north at noon", 60, 0),
    ],
)
def test_times_of_day_and_directions_place_the_sun(
    phrase: str, elevation: float, azimuth: float
) -> None:
    r = read_phrase(phrase)
    assert (r.sun_elevation_deg, r.sun_azimuth_deg) == (elevation, azimuth)
    assert r.unknown == ()


def test_overcast_and_cool_and_a_repeated_word() -> None:
    r = read_phrase("cloudy noon, cool, sunny")
    assert r.model == "preetham" and r.turbidity == 2.5  # the last weather counts
    assert any("replaces" in note for note in r.notes)
    r = read_phrase("overcast, cold")
    assert r.model == "cie-overcast" and r.tint_rgb is not None and r.tint_rgb[2] > r.tint_rgb[0]


def test_studio_phrases_become_studio_lights() -> None:
    r = read_phrase("softbox from the left")
    assert r.is_studio and r.lights is not None
    assert [(light.kind, light.azimuth_deg) for light in r.lights] == [("softbox", 270.0)]
    r = read_phrase("studio key light from the right, fill light, rim light")
    assert r.lights is not None
    kinds = {light.kind: light.azimuth_deg for light in r.lights}
    assert kinds == {"key": 90.0, "fill": 270.0, "rim": 0.0}  # the fill mirrors the key
    r = read_phrase("studio")
    assert r.lights is not None and [light.kind for light in r.lights] == ["softbox", "fill"]
    r = read_phrase("sunset softbox from above")
    assert r.lights is not None and r.lights[0].elevation_deg == 80.0
    assert any("sunset" in note and "ignored" in note for note in r.notes)
    assert isinstance(r.scene(), StudioConfig)


def test_every_documented_phrase_is_understood() -> None:
    for kind, phrases in VOCABULARY.items():
        for phrase in phrases:
            for variant in phrase.split(" / "):
                r = read_phrase(variant)
                assert r.unknown == (), (kind, variant, r.unknown)
                if kind != "filler":
                    assert r.understood, (kind, variant)


def test_grammar_is_documented_in_the_tutorial() -> None:
    doc = Path(__file__).parents[3] / "docs" / "tutorials" / "skies.md"
    if not doc.exists():
        pytest.skip("docs/ is not beside this package")
    text = doc.read_text()
    for kind in ("time of day", "weather", "colour", "direction", "studio"):
        for phrase in VOCABULARY[kind]:
            for variant in phrase.split(" / "):
                assert variant in text, variant


# --------------------------------------------------------------------------- the command line


def test_cli_writes_a_sky_that_reads_back(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "sub" / "sky.exr"
    preview = tmp_path / "sky.png"
    argv = ["sky", "--out", str(out), "--sun-elevation", "20", "--sun-azimuth", "100"]
    assert main([*argv, "--width", "64", "--preview", str(preview)]) == 0
    env = read_envmap(out)
    assert env.radiance_linear.shape == (32, 64, 3) and preview.stat().st_size > 0
    assert env.metadata["gaffer:sky_model"] == "preetham"  # provenance in the EXR header
    assert float(env.metadata["gaffer:sun_azimuth_deg"]) == 100.0
    lum = env.radiance_linear @ LUMA
    i, j = np.unravel_index(int(np.argmax(lum)), lum.shape)
    u, v = direction_to_uv(sun_direction(20, 100))
    assert (i, j) == (int(v * 32), int(u * 64))
    assert "wrote" in capsys.readouterr().out


def test_cli_text_prints_what_it_understood(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "s.exr"
    assert main(["sky", "--out", str(out), "--width", "32", "--text", "hazy sunset, fluffy"]) == 0
    printed = capsys.readouterr().out
    assert '"sunset"' in printed and '"hazy"' in printed
    assert "not understood (ignored): fluffy" in printed
    assert out.exists()
    studio = tmp_path / "studio.exr"
    assert (
        main(["sky", "--out", str(studio), "--width", "32", "--text", "softbox from the left"]) == 0
    )
    assert "softbox at azimuth 270" in capsys.readouterr().out


def test_cli_says_when_the_phrase_gave_no_time_of_day(tmp_path: Path, capsys) -> None:
    assert main(["sky", "--out", str(tmp_path / "s.exr"), "--width", "16", "--text", "hazy"]) == 0
    assert "no time of day" in capsys.readouterr().out


def test_cli_explicit_angles_override_the_phrase(tmp_path: Path, capsys) -> None:
    out = tmp_path / "s.exr"
    argv = ["sky", "--out", str(out), "--width", "32", "--text", "sunset", "--sun-azimuth", "0"]
    assert main(argv) == 0
    assert "elevation 1.0 deg, azimuth 0.0 deg" in capsys.readouterr().out


def test_cli_ephemeris(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    pytest.importorskip("astral")
    out = tmp_path / "s.exr"
    argv = ["sky", "--out", str(out), "--width", "32", "--at=-33.8688,151.2093"]
    assert main([*argv, "--time", "2024-06-21T12:00+10:00"]) == 0
    assert "elevation 32." in capsys.readouterr().out


def test_cli_missing_astral_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setitem(sys.modules, "astral", None)
    monkeypatch.setitem(sys.modules, "astral.sun", None)
    out = tmp_path / "s.exr"
    argv = ["sky", "--out", str(out), "--at", "1,2", "--time", "2024-06-21T12:00Z"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'pip install "gaffer-envmap[sky]"' in err[0]
    assert not out.exists()


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        ([], "no sun position"),
        (["--sun-elevation", "10"], "`--sun-azimuth` is missing"),
        (["--at", "1,2"], "`--at` needs `--time`"),
        (["--time", "2024-06-21T12:00Z"], "`--time` needs `--at`"),
        (["--at", "1,2", "--time", "2024-06-21T12:00"], "`--time`"),
        (["--at", "1,2", "--time", "2024-06-21T12:00", "--sun-elevation", "3"], "both give"),
        (["--at", "95,2", "--time", "2024-06-21T12:00Z"], "`--at`"),
        (["--text", "noon fluffy", "--strict"], "'fluffy'"),
        (["--text", "softbox", "--turbidity", "4"], "`--turbidity` applies to skies"),
    ],
)
def test_cli_refusals_are_one_line_and_write_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture, extra: list[str], words: str
) -> None:
    out = tmp_path / "s.exr"
    assert main(["sky", "--out", str(out), "--width", "32", *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--sun-elevation", "91", "--sun-azimuth", "0"], "--sun-elevation"),
        (["--sun-elevation", "nan", "--sun-azimuth", "0"], "--sun-elevation"),
        (["--turbidity", "1", "--text", "noon"], "--turbidity"),
        (["--width", "33", "--text", "noon"], "--width"),
        (["--ground-albedo", "0.2,2,0.2", "--text", "noon"], "--ground-albedo"),
        (["--model", "hosek", "--text", "noon"], "--model"),
    ],
)
def test_cli_nonsense_numbers_are_refused_by_the_parser(
    tmp_path: Path, capsys: pytest.CaptureFixture, extra: list[str], words: str
) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["sky", "--out", str(tmp_path / "s.exr"), *extra])
    assert exit_info.value.code == 2
    assert words in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_cli_refuses_bad_output_paths_before_work(tmp_path: Path, capsys) -> None:
    (tmp_path / "afile").write_text("x")
    for out, words in (
        (tmp_path / "s.png", "pass a .exr file"),
        (tmp_path / "afile" / "s.exr", "is a file"),
        (tmp_path, "is a folder"),
    ):
        assert main(["sky", "--out", str(out), "--text", "noon"]) == 2
        assert words in capsys.readouterr().err
    assert (
        main(["sky", "--out", str(tmp_path / "s.exr"), "--text", "noon", "--preview", "p.jpg"]) == 2
    )
    assert "`--preview`" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


# --------------------------------------------------------------------------- Blender agreement

SKY_WORKER = Path(__file__).parent / "_blender_scripts" / "bpy_sky_worker.py"


def _blender_skies(tmp_path: Path, renders: list[dict]) -> list[np.ndarray]:
    """Bake Blender's Sky Texture to 128 x 64 lat-long maps (bpy in a subprocess, never here)."""
    import json
    import subprocess

    import OpenEXR

    for k, item in enumerate(renders):
        item.update(out=str(tmp_path / f"blender_{k}.exr"), width=128, height=64)
    job = tmp_path / "job.json"
    result = tmp_path / "result.json"
    job.write_text(json.dumps({"threads": 2, "result": str(result), "renders": renders}))
    proc = subprocess.run(
        [sys.executable, str(SKY_WORKER), str(job)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    maps = []
    for item in renders:
        channels = OpenEXR.File(item["out"], separate_channels=True).channels()
        maps.append(np.stack([np.asarray(channels[c].pixels, np.float64) for c in "RGB"], -1))
    return maps


@pytest.mark.blender
@pytest.mark.skipif(
    importlib.util.find_spec("bpy") is None, reason="needs bpy (gaffer-data[render])"
)
def test_sun_direction_and_preetham_sky_agree_with_blenders_sky_texture(tmp_path: Path) -> None:
    """Blender's `sun_rotation` convention and its Preetham sky, as Cycles draws them, against ours.

    The sun: Blender's multiple-scattering sky with a 6-degree disc, baked by the panoramic camera whose
    layout is our Blender lat-long (test_blender_agreement.py 1a): its brightest pixel is our
    `sun_direction(elevation, rotation)`. The sky: Blender's PREETHAM type (given the same sun as a
    vector) has our `preetham_sky` luminance pattern up to one constant scale, and our colours.
    """
    suns = [(30.0, 90.0), (50.0, 37.0), (15.0, 250.0)]
    preetham = [(30.0, 90.0, 3.0), (10.0, 200.0, 5.0)]
    renders = [
        {"sky_type": "MULTIPLE_SCATTERING", "sun_elevation_deg": el, "sun_rotation_deg": az}
        | {"sun_size_deg": 6.0}
        for el, az in suns
    ] + [
        {"sky_type": "PREETHAM", "sun_elevation_deg": el, "sun_rotation_deg": az, "turbidity": t}
        for el, az, t in preetham
    ]
    maps = _blender_skies(tmp_path, renders)
    dirs = direction_grid(64, 128)
    for (el, az), blender in zip(suns, maps[: len(suns)], strict=True):
        lum = blender @ LUMA
        i, j = np.unravel_index(int(np.argmax(lum)), lum.shape)
        assert _angle_deg(dirs[i, j], sun_direction(el, az)) < 2.0, (el, az)  # a pixel is 2.8 deg
    sky = dirs[..., 2] > 0.05
    for (el, az, t), blender in zip(preetham, maps[len(suns) :], strict=True):
        ours = preetham_sky(dirs, sun_direction(el, az), t)[sky]
        theirs = blender[sky]
        ratio = (theirs @ LUMA) / (ours @ LUMA)
        assert ratio.max() / ratio.min() < 1.005, (el, az, t)  # one scale everywhere
        chroma = np.abs(theirs / ratio[:, None] - ours) / (ours @ LUMA)[:, None]
        assert chroma.max() < 2e-3, (el, az, t)
