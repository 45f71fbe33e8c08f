"""Nonsense numbers and paths are refused with the argument named (issue 17)."""

import pytest

from gaffer_envmap.cli import main


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["rotate", "a.exr", "b.exr", "--w2c", "p.npy", "--spin", "nan"], "finite"),
        (["encode", "a.exr", "--w2c", "p.npy", "--out-dir", "o", "--spin", "inf"], "finite"),
        (["augment", "a.exr", "--out-dir", "o", "--yaw-steps", "0"], "integer >= 1"),
        (["rotate", "a.exr", "b.exr", "--w2c", "p.npy", "--supersample", "0"], "integer >= 1"),
    ],
)
def test_nonsense_numbers_are_refused_by_the_parser(capsys, argv, words) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    assert words in capsys.readouterr().err
