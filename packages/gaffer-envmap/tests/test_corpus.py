"""Real files from the OpenEXR sample collection (`../shared/corpus/openexr-images`).

- `Damaged/`: 185 fuzzer-made broken files; every one must be refused with `EnvmapReadError`, in
  this process (no subprocess), without a crash, a hang or a huge allocation.
- `TestImages/` and `MultiResolution/`: load, or are refused, as `gaffer_envmap.io_exr` documents.
"""

import time
from pathlib import Path

import numpy as np
import pytest

from gaffer_envmap._exr_header import ExrCorruptError, validate_exr
from gaffer_envmap.errors import EnvmapReadError, NonFiniteError, ShapeError
from gaffer_envmap.io import read_envmap, read_image_array
from gaffer_envmap.io_exr import read_exr_array
from gaffer_envmap.sanitize import sanitize

pytestmark = pytest.mark.corpus

CORPUS = Path(__file__).resolve().parents[3] / ".." / "shared" / "corpus" / "openexr-images"
DAMAGED_BUDGET_S = 20.0


@pytest.fixture(scope="module")
def corpus() -> Path:
    if not CORPUS.is_dir():
        pytest.skip(f"corpus not found at {CORPUS}")
    return CORPUS


def _damaged_files(corpus: Path) -> list[Path]:
    return sorted(p for p in (corpus / "Damaged").iterdir() if p.is_file() and p.suffix != ".rst")


def test_every_damaged_file_is_refused(corpus: Path) -> None:
    files = _damaged_files(corpus)
    assert len(files) == 185
    accepted = []
    start = time.perf_counter()
    for path in files:
        try:
            read_exr_array(path)  # the EXR reader itself: these files have no .exr suffix
        except EnvmapReadError as exc:
            assert str(path) in str(exc)
        else:
            accepted.append(path.name)
    elapsed = time.perf_counter() - start
    assert accepted == []
    assert elapsed < DAMAGED_BUDGET_S, f"refusing the damaged corpus took {elapsed:.1f} s"


def test_damaged_files_are_refused_before_native_decoding(corpus: Path) -> None:
    """The pure-Python validator, not OpenEXR, is what stops (nearly) all of them."""
    passed_validation = []
    for path in _damaged_files(corpus):
        try:
            validate_exr(path)
        except ExrCorruptError:
            continue
        passed_validation.append(path.name)
    # One file has a sound structure and only corrupt PIZ data; OpenEXR reports it as undecodable.
    assert passed_validation == [
        "asan_heap-oob_7f171b7ab3a2_937_b4e2415c399c2ab39548de911223769d_exr"
    ]


def test_all_half_values(corpus: Path) -> None:
    path = corpus / "TestImages" / "AllHalfValues.exr"
    pixels = read_image_array(path)
    assert pixels.shape == (256, 256, 3) and pixels.dtype == np.float32
    finite_or_inf = pixels[~np.isnan(pixels)]
    # half -> float32 is exact: all 65536 - 2046 non-NaN half bit patterns come back distinct
    assert len(np.unique(finite_or_inf.astype(np.float16).view(np.uint16))) == 63490
    assert np.isposinf(pixels).any() and np.isneginf(pixels).any() and np.isnan(pixels).any()
    with pytest.raises(ShapeError, match="twice as wide"):
        read_envmap(path)
    clean, report = sanitize(pixels, "clamp")
    assert np.isfinite(clean).all() and (clean >= 0).all()
    assert report.num_posinf > 0 and report.num_neginf > 0 and report.num_negative > 0
    assert report.posinf_replacement == 65504.0


def test_bright_rings(corpus: Path) -> None:
    clean = read_image_array(corpus / "TestImages" / "BrightRings.exr")
    dirty = read_image_array(corpus / "TestImages" / "BrightRingsNanInf.exr")
    assert clean.shape == dirty.shape == (800, 800, 3)
    assert np.isfinite(clean).all() and clean.max() > 1000
    bad = ~np.isfinite(dirty)
    assert 0 < bad.sum() < 100
    np.testing.assert_array_equal(dirty[~bad.any(-1)], clean[~bad.any(-1)])
    with pytest.raises(NonFiniteError, match="NaN"):
        sanitize(dirty, "raise", name="BrightRingsNanInf.exr")


def test_wide_float_range_is_refused_for_lack_of_colour(corpus: Path) -> None:
    with pytest.raises(EnvmapReadError, match=r"\[\['G'\]\]"):
        read_image_array(corpus / "TestImages" / "WideFloatRange.exr")


@pytest.mark.parametrize(
    ("name", "shape"),
    [
        ("KernerEnvLatLong", (512, 1024)),
        ("StageEnvLatLong", (500, 1000)),
        ("OrientationLatLong", (512, 1024)),
        ("WavyLinesLatLong", (512, 1024)),
    ],
)
def test_mipmapped_latlong_maps_load_base_level(
    corpus: Path, name: str, shape: tuple[int, int]
) -> None:
    env = read_envmap(
        corpus / "MultiResolution" / f"{name}.exr", convention="openexr", alignment="corner"
    )
    assert (env.height, env.width) == shape
    assert env.metadata["envmap"] == "latlong"
    assert env.metadata["exr_storage"] == "tiledimage"
    assert np.isfinite(env.radiance_linear).all() and env.radiance_linear.max() > 0


@pytest.mark.parametrize(
    ("name", "face"), [("KernerEnvCube", 256), ("OrientationCube", 512), ("WavyLinesCube", 256)]
)
def test_cube_maps_load_as_arrays_not_as_envmaps(corpus: Path, name: str, face: int) -> None:
    path = corpus / "MultiResolution" / f"{name}.exr"
    assert read_image_array(path).shape[:2] == (6 * face, face)
    with pytest.raises(ShapeError, match="cube_to_latlong"):
        read_envmap(path)
