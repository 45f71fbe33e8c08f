"""`gaffer_envmap.sanitize`: counts per value and the three policies."""

import logging

import numpy as np
import pytest

from gaffer_envmap.errors import NonFiniteError
from gaffer_envmap.sanitize import SanitizeReport, sanitize


def _dirty() -> np.ndarray:
    x = np.linspace(0.5, 7.5, 24, dtype=np.float32).reshape(2, 4, 3)
    x[0, 0, 0] = np.nan
    x[0, 1, 2] = np.nan
    x[1, 0, 1] = np.inf
    x[1, 2, 0] = -np.inf
    x[1, 2, 1] = -np.inf
    x[1, 3, 2] = -2.0
    x[0, 3, 0] = -0.25
    x[0, 3, 1] = -1e-30
    return x


def test_clean_input_is_returned_unchanged() -> None:
    x = np.ones((2, 4, 3), np.float32)
    x[0, 0, 0] = -0.0  # negative zero is not a negative value
    out, report = sanitize(x, "raise")
    assert out is x
    assert report.clean
    assert report == SanitizeReport(
        num_nan=0, num_posinf=0, num_neginf=0, num_negative=0, policy="raise"
    )


def test_counts_are_per_value() -> None:
    _, report = sanitize(_dirty(), "zero")
    assert (report.num_nan, report.num_posinf, report.num_neginf, report.num_negative) == (
        2,
        1,
        2,
        3,
    )
    assert report.num_bad == 8
    assert report.describe() == "2 NaN, 1 +Inf, 2 -Inf, 3 negative"


def test_raise_names_counts_and_fix() -> None:
    x = _dirty()
    with pytest.raises(NonFiniteError) as info:
        sanitize(x, "raise", name="sky.exr")
    msg = str(info.value)
    assert "sky.exr" in msg
    assert "2 NaN, 1 +Inf, 2 -Inf, 3 negative" in msg
    assert 'sanitize="zero"' in msg and 'sanitize="clamp"' in msg


def test_zero_policy() -> None:
    x = _dirty()
    before = x.copy()
    out, report = sanitize(x, "zero")
    bad = ~np.isfinite(before) | (before < 0)
    assert np.array_equal(out[bad], np.zeros(int(bad.sum()), np.float32))
    assert np.array_equal(out[~bad], before[~bad])
    assert report.posinf_replacement == 0.0
    np.testing.assert_array_equal(x, before)  # input untouched
    assert out.dtype == np.float32


def test_clamp_policy_uses_largest_finite_value() -> None:
    x = _dirty()
    x[0, 2, 2] = 1234.5
    out, report = sanitize(x, "clamp")
    assert out[1, 0, 1] == np.float32(1234.5)
    assert report.posinf_replacement == pytest.approx(1234.5)
    assert out[0, 0, 0] == 0 and out[1, 2, 0] == 0 and out[1, 3, 2] == 0 and out[0, 3, 1] == 0
    assert np.isfinite(out).all() and (out >= 0).all()


def test_clamp_without_finite_values_uses_zero() -> None:
    x = np.array([np.inf, np.nan, -np.inf], np.float32)
    out, report = sanitize(x, "clamp")
    assert out.tolist() == [0.0, 0.0, 0.0]
    assert report.posinf_replacement == 0.0


def test_preserves_half_dtype() -> None:
    x = np.array([1.0, np.inf, -3.0], np.float16)
    out, _ = sanitize(x, "clamp")
    assert out.dtype == np.float16
    assert out.tolist() == [1.0, 1.0, 0.0]


def test_unknown_policy() -> None:
    with pytest.raises(ValueError, match="`policy`"):
        sanitize(np.ones(3), "inpaint")  # type: ignore[arg-type]


def test_raise_sets_tiny_compression_negatives_to_zero_with_an_info_line(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # lossy EXR compression leaves a few negatives far below the map's scale
    x = np.ones((8, 16, 3), np.float32)
    x[2, 3, 1] = -1e-3
    x[5, 7, 0] = -4e-2
    with caplog.at_level(logging.INFO, logger="gaffer_envmap.sanitize"):
        out, report = sanitize(x, "raise", name="sky.exr")
    assert report.tiny_negatives_clamped and report.num_negative == 2
    assert out.min() == 0.0 and out[2, 3, 1] == 0.0 and out[0, 0, 0] == 1.0
    assert x[2, 3, 1] == np.float32(-1e-3)  # the input is not modified
    assert "sky.exr" in caplog.text and "tiny negative" in caplog.text


@pytest.mark.parametrize(
    "make",
    [
        lambda x: x.__setitem__((0, 0, 0), -0.1),  # 10 % of the mean: a real error
        lambda x: x.__setitem__((slice(0, 2),), -1e-4),  # a quarter of the values negative
        lambda x: x.__setitem__((0, 0, 0), np.nan),
    ],
    ids=["large", "many", "nan"],
)
def test_raise_still_refuses_substantial_negatives_and_nan(make) -> None:
    x = np.ones((8, 16, 3), np.float32)
    make(x)
    with pytest.raises(NonFiniteError):
        sanitize(x, "raise")


def test_strict_refuses_even_tiny_negatives() -> None:
    x = np.ones((8, 16, 3), np.float32)
    x[2, 3, 1] = -1e-6
    with pytest.raises(NonFiniteError, match="1 negative"):
        sanitize(x, "strict")


def test_every_bundled_hdri_reads_with_the_default_policy() -> None:
    from gaffer_envmap import bundled_hdris, read_envmap

    for name, path in bundled_hdris().items():
        env = read_envmap(path)
        assert env.radiance_linear.min() >= 0.0, name
