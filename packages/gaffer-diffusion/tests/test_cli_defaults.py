"""The CLI takes gaffer-tiny's own encoding and framing when no --checkpoint is given, the authors'
otherwise, and an explicit flag always wins."""

import argparse
from pathlib import Path

import pytest

from gaffer_diffusion import pretrained
from gaffer_diffusion.cli import _compat, _object_fraction, _parser
from gaffer_diffusion.errors import ConfigError
from gaffer_diffusion.suggested import read_default_sampling


def _args(*extra: str) -> argparse.Namespace:
    return _parser().parse_args(["evaluate", "--dataset", "d", *extra])


def test_defaults_follow_the_model() -> None:
    shipped = _args()
    own = read_default_sampling(pretrained.gaffer_tiny_path())  # gaffer-tiny's manifest
    assert _compat(shipped) == own.compat == "default"
    assert _object_fraction(shipped) == own.object_fraction == 0.75
    other = _args("--checkpoint", "ckpt")
    assert other.checkpoint == Path("ckpt")
    assert _compat(other) == "neural-gaffer" and _object_fraction(other) is None


def test_explicit_flags_win_and_bad_fractions_are_refused() -> None:
    a = _args("--checkpoint", "ckpt", "--compat", "default", "--object-fraction", "0.5")
    assert _compat(a) == "default" and _object_fraction(a) == 0.5
    assert _compat(_args("--compat", "neural-gaffer")) == "neural-gaffer"
    for bad in ("0", "1.5", "-0.2"):
        with pytest.raises(ConfigError, match="--object-fraction"):
            _object_fraction(_args("--object-fraction", bad))


def test_demo_and_relight_accept_the_new_flags() -> None:
    d = _parser().parse_args(
        ["demo", "--out", "o", "--compat", "default", "--object-fraction", "0.8"]
    )
    assert d.compat == "default" and d.object_fraction == 0.8
    r = _parser().parse_args(["relight", "x.png", "--envmap", "e.exr", "--out", "o.png"])
    assert r.compat is None


@pytest.mark.parametrize("flag", ["--steps", "--average-samples"])
def test_an_explicit_zero_is_refused_not_read_as_the_default(flag) -> None:
    from gaffer_diffusion.cli import _sampling

    for ckpt in ([], ["--checkpoint", "somewhere"]):
        args = _parser().parse_args(["relight", "x.png", "--out", "o.png", flag, "0", *ckpt])
        with pytest.raises(ConfigError, match=flag):
            _sampling(args)
    ok = _sampling(_parser().parse_args(["relight", "x.png", "--out", "o.png"]))
    assert ok.num_inference_steps == pretrained.gaffer_tiny_sampling().num_inference_steps == 1
