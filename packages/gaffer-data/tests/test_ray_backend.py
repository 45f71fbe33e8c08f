"""`--backend ray` against a local Ray instance: same outputs as `--backend local`, resume, errors."""

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ray")
# The Ray tasks start Blender workers; this process must never import bpy, so only look it up.
if importlib.util.find_spec("bpy") is None:
    pytest.skip("bpy is not installed (gaffer-data[render])", allow_module_level=True)

import ray

from gaffer_data.cli import main
from gaffer_data.dataset import open_dataset, read_object
from gaffer_data.errors import MissingDependencyError
from gaffer_data.recipes import scan_objects
from gaffer_data.render.plan import scan_envmaps
from gaffer_data.render.ray_backend import RayDispatch, RayOptions
from gaffer_data.render.runner import RunOptions, render_dataset
from gaffer_data.testing import (
    read_exr,
    tiny_config,
    write_cube_obj,
    write_uniform_envmaps,
    write_uv_sphere_obj,
)

pytestmark = pytest.mark.blender

COLORS = {"red": (1.0, 0.02, 0.02), "blue": (0.02, 0.02, 1.0)}


def _png(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        return np.array(im)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("inputs")
    write_cube_obj(root / "objects" / "cube.obj")
    write_uv_sphere_obj(root / "objects" / "sphere.obj")
    (root / "objects" / "broken.glb").write_bytes(b"glTF\x02\x00\x00\x00garbage")
    write_uniform_envmaps(root / "envmaps", COLORS)
    return root / "objects", root / "envmaps"


@pytest.fixture(scope="module")
def local_ray():
    # One small instance for the module (starting Ray takes seconds); RayDispatch joins it as is.
    ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def _render(inputs: tuple[Path, Path], out: Path, dispatch: RayDispatch | None):
    objects, envmaps = inputs
    return render_dataset(
        scan_objects(objects),
        scan_envmaps(envmaps),
        out,
        tiny_config(views=1, lightings=2),
        RunOptions(workers=2, retries=1, progress=False),
        dispatch=dispatch,
    )


@pytest.fixture(scope="module")
def rendered(inputs, local_ray, tmp_path_factory: pytest.TempPathFactory):
    out_local, out_ray = tmp_path_factory.mktemp("local"), tmp_path_factory.mktemp("ray")
    local = _render(inputs, out_local, None)
    remote = _render(inputs, out_ray, RayDispatch())
    return out_local, local, out_ray, remote


def test_ray_outputs_equal_local_outputs(rendered) -> None:
    out_local, local, out_ray, remote = rendered
    assert remote.rendered == local.rendered == ("cube", "sphere")
    assert remote.images == local.images == 2 * (2 + 1)
    for oid in remote.rendered:
        a, b = read_object(out_local / "objects" / oid), read_object(out_ray / "objects" / oid)
        assert a.views == b.views  # cameras, envmap draws and augmentations
        pa, pb = a.poses(), b.poses()
        np.testing.assert_array_equal(pa.w2c_blender, pb.w2c_blender)
        np.testing.assert_array_equal(pa.c2w_opencv, pb.c2w_opencv)
        assert [f.path for f in a.files] == [f.path for f in b.files]
        for fa, fb in zip(a.files, b.files):
            if fa.path.endswith(".exr"):
                ca, cb = read_exr(a.path(fa.path)), read_exr(b.path(fb.path))
                assert sorted(ca) == sorted(cb)
                for key in ca:
                    np.testing.assert_array_equal(ca[key], cb[key])
            elif fa.path.endswith(".png"):
                # Pixels, not files: Blender stamps the render date into PNG metadata.
                np.testing.assert_array_equal(_png(a.path(fa.path)), _png(b.path(fb.path)))
    assert open_dataset(out_ray).object_ids == ("cube", "sphere")


def test_ray_records_failures_like_local(rendered) -> None:
    _, local, out_ray, remote = rendered
    assert [f.object_id for f in remote.failed] == ["broken"]
    assert remote.failed[0].attempts == local.failed[0].attempts == 1  # input errors: no retry
    assert "broken.glb" in remote.failed[0].reason
    assert [f.object_id for f in open_dataset(out_ray).failures] == ["broken"]
    line = (out_ray / "failures.jsonl").read_text().splitlines()[0]
    assert json.loads(line)["object_id"] == "broken"


def test_ray_rerun_skips_complete_objects(rendered, inputs) -> None:
    _, _, out_ray, _ = rendered
    objects, envmaps = inputs
    before = (out_ray / "objects" / "cube" / "manifest.json").stat().st_mtime_ns
    summary = render_dataset(
        [("cube", objects / "cube.obj"), ("sphere", objects / "sphere.obj")],
        scan_envmaps(envmaps),
        out_ray,
        tiny_config(views=1, lightings=2),
        RunOptions(workers=2, progress=False),
        dispatch=RayDispatch(),
    )
    assert summary.skipped == ("cube", "sphere") and summary.rendered == () and summary.images == 0
    assert (out_ray / "objects" / "cube" / "manifest.json").stat().st_mtime_ns == before


def test_missing_ray_names_the_backend_and_the_extra(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # makes `import ray` raise ImportError
    with pytest.raises(MissingDependencyError, match=r"--backend ray.*gaffer-data\[ray\]"):
        RayDispatch()
    argv = ["render", "--objects", str(tmp_path), "--envmaps", str(tmp_path)]
    assert main([*argv, "--out", str(tmp_path / "out"), "--backend", "ray"]) == 2
    err = capsys.readouterr().err
    assert "`--backend ray`" in err and 'pip install "gaffer-data[ray]"' in err


def test_ray_only_options_need_the_ray_backend(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    argv = ["render", "--objects", str(tmp_path), "--envmaps", str(tmp_path)]
    assert main([*argv, "--out", str(tmp_path / "out"), "--cpus-per-task", "2"]) == 2
    assert "--backend ray" in capsys.readouterr().err
    with pytest.raises(ValueError, match="cpus_per_task"):
        RayOptions(cpus_per_task=0)


def test_cli_backend_ray(
    local_ray, inputs, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    envmaps = inputs[1]
    write_cube_obj(tmp_path / "objects" / "cube.obj")
    argv = ["render", "--objects", str(tmp_path / "objects"), "--envmaps", str(envmaps)]
    argv += ["--out", str(tmp_path / "out"), "--views", "1", "--lightings", "1"]
    argv += ["--resolution", "32", "--samples", "4", "--no-denoise", "--world-map-resolution", "64"]
    argv += ["--no-progress", "--backend", "ray", "--cpus-per-task", "1"]
    assert main(argv) == 0
    assert "rendered 1 objects (2 images" in capsys.readouterr().out
    assert open_dataset(tmp_path / "out").object_ids == ("cube",)
