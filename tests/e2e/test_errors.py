"""One error vocabulary across the four packages."""


def test_every_package_shape_error_is_the_one_shape_error() -> None:
    # ShapeError is defined once (gaffer_envmap.errors) and each package subclasses it
    import importlib

    from gaffer_envmap.errors import GafferError, ShapeError

    for pkg in ("gaffer_diffusion", "gaffer_nerf"):
        errors = importlib.import_module(f"{pkg}.errors")
        err = errors.ShapeError("x", (2, 3), "[3]", "Reshape it.")
        assert isinstance(err, ShapeError) and isinstance(err, ValueError)
        assert str(err) == "`x` has shape (2, 3), expected [3]. Reshape it."
        assert err.diagnostics() == str(err)
    for pkg, base in (
        ("gaffer_data", "GafferDataError"),
        ("gaffer_diffusion", "GafferDiffusionError"),
        ("gaffer_nerf", "GafferNerfError"),
    ):
        errors = importlib.import_module(f"{pkg}.errors")
        assert issubclass(getattr(errors, base), GafferError)
