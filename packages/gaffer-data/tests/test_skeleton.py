import gaffer_data


def test_version_is_semver() -> None:
    parts = gaffer_data.__version__.split(".")
    assert len(parts) == 3 and all(p.isdigit() for p in parts)
