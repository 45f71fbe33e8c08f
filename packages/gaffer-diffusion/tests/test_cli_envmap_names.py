"""`relight --envmap NAME` takes the HDRIs bundled with gaffer-envmap by name."""

from pathlib import Path

from gaffer_diffusion.cli import _parser
from gaffer_envmap import bundled_hdris


def test_a_bundled_name_resolves_to_its_file_and_a_path_stays_a_path(tmp_path: Path) -> None:
    args = _parser().parse_args(["relight", "in.png", "--envmap", "night", "--out", "o.png"])
    assert args.envmap == bundled_hdris()["night"] and args.envmap.is_file()
    own = tmp_path / "night"  # a user's file of that name wins over the bundled map
    own.write_bytes(b"")
    args = _parser().parse_args(["relight", "in.png", "--envmap", str(own), "--out", "o.png"])
    assert args.envmap == own
    args = _parser().parse_args(["relight", "in.png", "--envmap", "nosuch", "--out", "o.png"])
    assert args.envmap == Path("nosuch")  # left for the reader's one-line error
