"""GPU twins of the CPU paths (run with --run-gpu on a CUDA machine; deselected elsewhere)."""

import numpy as np
import pytest
import torch

from gaffer_envmap import encode_lighting, orbit_w2c_blender, rotate_to_camera
from gaffer_envmap.testing import smooth_random_map

pytestmark = pytest.mark.gpu


@pytest.fixture
def cuda() -> torch.device:
    if not torch.cuda.is_available():
        pytest.fail("--run-gpu was given but CUDA is not available")
    return torch.device("cuda")


def test_rotation_and_encodings_match_cpu(cuda: torch.device) -> None:
    env = smooth_random_map(64, seed=0).radiance_linear * 20
    poses = [orbit_w2c_blender(a, e) for a, e in ((0, 0), (40, 30), (250, -45))]
    cpu = rotate_to_camera(env, poses, height=32)
    gpu = rotate_to_camera(torch.from_numpy(env).to(cuda), poses, height=32)
    torch.testing.assert_close(gpu.cpu(), cpu, rtol=1e-4, atol=1e-4)
    for compat in ("default", "neural-gaffer"):
        a = encode_lighting(env, poses, size=64, compat=compat)
        b = encode_lighting(torch.from_numpy(env).to(cuda), poses, size=64, compat=compat)
        assert b.ldr.device.type == "cuda"
        tol = 1 / 255 + 1e-6 if compat == "neural-gaffer" else 1e-4
        torch.testing.assert_close(b.ldr.cpu(), a.ldr, rtol=0, atol=tol)
        torch.testing.assert_close(b.hdr.cpu(), a.hdr, rtol=0, atol=tol)
    assert np.isfinite(gpu.cpu().numpy()).all()
