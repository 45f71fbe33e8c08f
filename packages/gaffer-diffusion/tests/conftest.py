"""Fixtures shared by the gaffer-diffusion tests."""

from collections.abc import Iterator

import pytest
import torch


@pytest.fixture
def one_thread() -> Iterator[None]:
    """One torch thread for the test, restored after it: tiny tensors gain nothing from more, and
    the shared 2-core CI machines slow down when threads compete. A module opts in with
    `pytestmark = pytest.mark.usefixtures("one_thread")`."""
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)
