"""`gaffer-envmap info --sanitize POLICY` reports what the policy would do, refusing nothing."""

import json
from pathlib import Path

import numpy as np
import pytest

from gaffer_envmap.cli import main
from gaffer_envmap.io import write_envmap


@pytest.fixture
def maps(tmp_path: Path) -> dict[str, Path]:
    clean = np.full((8, 16, 3), 0.5, np.float32)
    tiny = clean.copy()
    tiny[0, 0, 0] = -0.001  # lossy-compression noise
    nan = clean.copy()
    nan[1, 1, 1] = np.nan
    out = {}
    for name, arr in (("clean", clean), ("tiny", tiny), ("nan", nan)):
        write_envmap(tmp_path / f"{name}.exr", arr)
        out[name] = tmp_path / f"{name}.exr"
    return out


@pytest.mark.parametrize(
    ("name", "policy", "words"),
    [
        ("clean", "strict", "strict: clean"),
        ("tiny", "raise", "raise: tiny negatives set to 0"),
        ("tiny", "strict", "strict: would refuse the map (0 NaN, 0 +Inf, 0 -Inf, 1 negative)"),
        ("nan", "raise", "raise: would refuse the map (1 NaN"),
        ("nan", "zero", "zero: zero: 1 NaN"),
    ],
)
def test_info_reports_the_policy(maps, capsys, name, policy, words) -> None:
    assert main(["info", str(maps[name]), "--json", "--sanitize", policy]) == 0
    report = json.loads(capsys.readouterr().out)
    assert words in report["sanitize"]
    # the stats still describe the raw map
    assert report["nan_count"] == (1 if name == "nan" else 0)


def test_info_defaults_to_the_commands_default_policy(maps, capsys) -> None:
    assert main(["info", str(maps["nan"])]) == 0
    assert "raise: would refuse the map" in capsys.readouterr().out
