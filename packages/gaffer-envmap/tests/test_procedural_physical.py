"""Random physically based maps (`gaffer_envmap.procedural_physical.physical_envmap`); its seeding,
arguments and export are tested beside `procedural_envmap`'s in test_procedural.py."""

import collections

import numpy as np

from gaffer_envmap.cli import main
from gaffer_envmap.io import read_envmap
from gaffer_envmap.procedural_physical import PHYSICAL_FAMILIES, physical_envmap

SEEDS = range(40)
_LUMA = np.array([0.2126, 0.7152, 0.0722])


def test_every_family_is_drawn_and_each_map_is_finite_hdr_in_the_exposure_range() -> None:
    families: collections.Counter[str] = collections.Counter()
    suns = 0
    for seed in SEEDS:
        env = physical_envmap(seed, height=32)
        e = env.radiance_linear
        family = env.metadata["gaffer:physical_family"]
        families[family] += 1
        assert e.shape == (32, 64, 3) and e.dtype == np.float32
        assert np.isfinite(e).all() and (e >= 0).all(), seed
        assert 0.1 * 0.999 <= float(e.mean()) <= 1.0 * 1.001, (seed, float(e.mean()))
        lum = e @ _LUMA
        if family == "preetham":
            # the sun: its disc's pixel outshines the sky (at this coarse height it fills a whole pixel)
            assert float(lum.max()) > 20.0 * float(np.median(lum)), seed
            # z up: the sun is above the horizon (rows 0-15 of 32)
            assert int(np.unravel_index(np.argmax(lum), lum.shape)[0]) < 16, seed
            suns += 1
        if family == "studio":
            assert float(lum.max()) > 3.0 * float(np.median(lum)), seed  # the lights stand out
    assert set(families) == set(PHYSICAL_FAMILIES), families
    assert families["preetham"] > families["cie-overcast"], families
    assert suns > 0, "no sunny sky among the seeds"


def test_cli_writes_the_physical_family(tmp_path) -> None:
    out = tmp_path / "maps"
    rc = main(
        [
            "procedural",
            "--out-dir",
            str(out),
            "--family",
            "physical",
            "--first",
            "3",
            "--count",
            "2",
            "--height",
            "8",
        ]
    )
    assert rc == 0
    assert sorted(p.name for p in out.iterdir()) == ["phys_0003.exr", "phys_0004.exr"]
    got = read_envmap(out / "phys_0004.exr").radiance_linear
    np.testing.assert_allclose(got, physical_envmap(4, height=8).radiance_linear, rtol=1e-3)
