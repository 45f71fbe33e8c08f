"""The render benchmark helper (benchmarks/_render_bench.py, not part of the gaffer-data wheel) on a
tiny scene (32 px): PSNR grows with samples, timings are sane."""

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

if importlib.util.find_spec("bpy") is None:
    pytest.skip("bpy is not installed (gaffer-data[render])", allow_module_level=True)

from gaffer_data.errors import ConfigError
from gaffer_data.render.plan import scan_envmaps
from gaffer_data.testing import write_exr, write_uv_sphere_obj

pytestmark = pytest.mark.blender

SCRIPT = Path(__file__).parents[2] / "benchmarks" / "_render_bench.py"


def _load_bench():
    """`benchmarks/_render_bench.py` as a module (benchmarks/ is scripts, not a package)."""
    spec = importlib.util.spec_from_file_location("_render_bench", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is built
    spec.loader.exec_module(module)
    return module


_bench = _load_bench()
RenderBenchConfig, bench_render, psnr = _bench.RenderBenchConfig, _bench.bench_render, _bench.psnr


def test_psnr() -> None:
    a = np.zeros((4, 4, 3))
    assert psnr(a, a) == math.inf
    assert psnr(a, a + 0.1) == pytest.approx(20.0)
    with pytest.raises(ConfigError, match="reference_samples"):
        RenderBenchConfig(samples=(64,), reference_samples=64)


def test_bench_render_tiny(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    write_exr(tmp_path / "env" / "noise.exr", rng.random((16, 32, 3)) * 4.0)
    sphere = write_uv_sphere_obj(tmp_path / "objects" / "sphere.obj")
    bench = RenderBenchConfig(
        resolutions=(32,),
        samples=(1, 16),
        denoise=(False, True),
        adaptive_thresholds=(0.0,),
        reference_samples=128,
        lightings=1,
        world_map_resolution=64,
        threads=1,
    )
    result = bench_render(
        [("sphere", sphere)], scan_envmaps(tmp_path / "env"), tmp_path / "w", bench
    )
    assert len(result.points) == 4 and result.images == 1 and result.cores == 1
    by = {(p.samples, p.denoise): p for p in result.points}
    assert all(p.seconds_per_image > 0 and np.isfinite(p.psnr_db) for p in result.points)
    assert by[(16, False)].psnr_db > by[(1, False)].psnr_db + 3.0
    assert by[(1, True)].psnr_db > by[(1, False)].psnr_db  # the denoiser removes noise
    best = result.fastest_reaching(by[(16, False)].psnr_db)
    assert best is not None and best.psnr_db >= by[(16, False)].psnr_db
    assert result.fastest_reaching(1e9) is None
