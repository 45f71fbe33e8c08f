import gaffer_diffusion


def test_version_is_semver() -> None:
    parts = gaffer_diffusion.__version__.split(".")
    assert len(parts) == 3 and all(p.isdigit() for p in parts)
