"""Fixtures of the gaffer-nerf tests: one thread, a seeded RNG, a shared tiny scene and fitted field."""

import dataclasses
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch

from gaffer_nerf.data.transforms import ViewSet
from gaffer_nerf.fit import FitResult, fit_tensorf
from gaffer_nerf.testing import orbit_cameras, quick_fit_config, scene_envmap, sphere_viewset


@pytest.fixture(scope="session", autouse=True)
def _one_thread() -> Iterator[None]:
    # Tiny tensors: intra-op threads only add contention on the shared 2-core CI machines.
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture
def rng() -> torch.Generator:
    return torch.Generator().manual_seed(0)


@dataclasses.dataclass(frozen=True)
class Scene:
    train: ViewSet
    test_input: ViewSet
    test_target: ViewSet
    env_target: object


@pytest.fixture(scope="session")
def scene() -> Scene:
    env0, env1 = scene_envmap(0), scene_envmap(1)
    cams, tcams = orbit_cameras(8), orbit_cameras(3, offset_deg=67.0)
    return Scene(
        train=sphere_viewset(cams, env0),
        test_input=sphere_viewset(tcams, env0),
        test_target=sphere_viewset(tcams, env1, lighting_index=1),
        env_target=env1,
    )


@pytest.fixture(scope="session")
def fitted(scene: Scene) -> FitResult:
    return fit_tensorf(scene.train, quick_fit_config())


@pytest.fixture
def tmp(tmp_path: Path) -> Path:
    return tmp_path
