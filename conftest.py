"""Root pytest configuration: markers and --run-* flags only (imports nothing from gaffer_*)."""

import os

import pytest

_OPT_IN = {"gpu": "GAFFER_RUN_GPU", "weights": "GAFFER_RUN_WEIGHTS"}


def pytest_addoption(parser: pytest.Parser) -> None:
    for marker, env in _OPT_IN.items():
        parser.addoption(
            f"--run-{marker}",
            action="store_true",
            default=os.environ.get(env) == "1",
            help=f"run tests marked `{marker}` (or set {env}=1)",
        )


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for marker in _OPT_IN:
        if config.getoption(f"--run-{marker}"):
            continue
        skip = pytest.mark.skip(reason=f"needs --run-{marker}")
        for item in items:
            if marker in item.keywords:
                item.add_marker(skip)
