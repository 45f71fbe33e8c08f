import gaffer_nerf


def test_version_is_semver() -> None:
    parts = gaffer_nerf.__version__.split(".")
    assert len(parts) == 3 and all(p.isdigit() for p in parts)
