"""Real Cycles renders of tiny scenes (32 px, 4 samples) through the Blender worker subprocesses."""

import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

# The workers need bpy; this process must never import it (pymeshlab, loaded by the filter tests,
# breaks a later `import bpy`), so only look it up.
if importlib.util.find_spec("bpy") is None:
    pytest.skip("bpy is not installed (gaffer-data[render])", allow_module_level=True)

from gaffer_data._atomic import is_stale_temporary
from gaffer_data.dataset import open_dataset, read_object
from gaffer_data.errors import ConfigError
from gaffer_data.recipes import scan_objects
from gaffer_data.render.plan import scan_envmaps
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
def rendered(inputs: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory):
    objects, envmaps = inputs
    out = tmp_path_factory.mktemp("render")
    summary = render_dataset(
        scan_objects(objects),
        scan_envmaps(envmaps),
        out,
        tiny_config(lightings=3),
        RunOptions(workers=1, retries=1, progress=False),
    )
    return out, summary


def test_outputs_exist_and_are_valid(rendered) -> None:
    out, summary = rendered
    assert summary.rendered == ("cube", "sphere") and summary.images == 2 * 2 * (3 + 1)
    ds = open_dataset(out)
    assert ds.object_ids == ("cube", "sphere")
    for obj in ds.iter_objects(verify=True):
        for view in obj.views:
            for lit in view.lit:
                ch = read_exr(obj.path(lit.exr))
                assert sorted(ch) == ["A", "B", "G", "R"]
                assert all(c.shape == (32, 32) and c.dtype == np.float32 for c in ch.values())
                assert all(np.isfinite(c).all() for c in ch.values())
                png = _png(obj.path(lit.png))
                assert png.shape == (32, 32, 4) and png.dtype == np.uint8
            assert view.area is not None and view.alpha is not None
            assert sorted(read_exr(obj.path(view.area.normal))) == ["B", "G", "R"]
            assert sorted(read_exr(obj.path(view.area.depth))) == ["Z"]
            assert _png(obj.path(view.alpha)).shape == (32, 32)
        poses = obj.poses()
        assert poses.w2c_blender.shape == (2, 3, 4)
    assert not [p for p in out.rglob(".*") if is_stale_temporary(p)]
    assert not list((out / "objects" / "cube").glob("_*")), (
        "private files of complete objects are removed"
    )


def test_broken_object_is_recorded_not_fatal(rendered) -> None:
    out, summary = rendered
    assert [f.object_id for f in summary.failed] == ["broken"]
    assert (
        "broken.glb" in summary.failed[0].reason and summary.failed[0].attempts == 1
    )  # input errors: no retry
    assert (out / "objects" / "broken" / "_worker.log").is_file()  # kept for debugging
    ds = open_dataset(out)
    assert [f.object_id for f in ds.failures] == ["broken"]
    assert json.loads((out / "failures.jsonl").read_text().splitlines()[0])["object_id"] == "broken"


def test_envmap_lit_pixels_follow_the_envmap(rendered) -> None:
    out, _ = rendered
    obj = read_object(out / "objects" / "sphere")
    seen = set()
    for view in obj.views:
        for lit in view.lit:
            ch = read_exr(obj.path(lit.exr))
            mask = ch["A"] > 0.99
            assert mask.sum() > 50
            r, b = ch["R"][mask].mean(), ch["B"][mask].mean()
            if lit.envmap.name == "red":
                assert r > 5 * b
            else:
                assert b > 5 * r
            seen.add(lit.envmap.name)
    assert seen == {"red", "blue"}


def test_alpha_mask_matches_geometry(rendered) -> None:
    out, _ = rendered
    obj = read_object(out / "objects" / "sphere")
    for view in obj.views:
        assert view.area is not None and view.alpha is not None
        alpha = _png(obj.path(view.alpha))
        depth = read_exr(obj.path(view.area.depth))["Z"]
        covered = depth < 1e6
        assert 0.05 < covered.mean() < 0.95
        assert np.mean((alpha > 127) != covered) < 0.03
        assert alpha[16, 16] == 255 and alpha[0, 0] == 0
        # The sphere's silhouette is a disc centred in the image (it sits at the origin).
        ys, xs = np.nonzero(alpha > 127)
        assert abs(xs.mean() - 15.5) < 1.0 and abs(ys.mean() - 15.5) < 1.0
        lit_alpha = read_exr(obj.path(view.lit[0].exr))["A"]
        assert np.mean((lit_alpha > 0.5) != (alpha > 127)) < 0.03


def test_normals_face_the_camera(rendered) -> None:
    out, _ = rendered
    obj = read_object(out / "objects" / "sphere")
    poses = obj.poses()
    for view in obj.views:
        assert view.area is not None
        ch = read_exr(obj.path(view.area.normal))
        n = np.stack([ch["R"], ch["G"], ch["B"]], -1)[16, 16]
        to_camera = np.asarray(view.camera.position) / np.linalg.norm(view.camera.position)
        assert float(n @ to_camera) > 0.95
        np.testing.assert_allclose(
            poses.c2w_opencv[view.index][:3, 3], view.camera.position, atol=1e-9
        )


def test_same_seed_gives_identical_images(rendered, inputs, tmp_path: Path) -> None:
    out, _ = rendered
    objects, envmaps = inputs
    render_dataset(
        [("sphere", objects / "sphere.obj")],
        scan_envmaps(envmaps),
        tmp_path,
        tiny_config(lightings=3),
        RunOptions(progress=False),
    )
    a, b = read_object(out / "objects" / "sphere"), read_object(tmp_path / "objects" / "sphere")
    assert a.views == b.views
    for fa, fb in zip(a.files, b.files):
        assert fa.path == fb.path
        if fa.path.endswith(".exr"):
            ca, cb = read_exr(a.path(fa.path)), read_exr(b.path(fb.path))
            for key in ca:
                np.testing.assert_array_equal(ca[key], cb[key])


def _object_bytes(folder: Path) -> dict[str, bytes]:
    """Every file of an object's folder but its manifest (whose `created_utc` is the write time)."""
    return {
        p.relative_to(folder).as_posix(): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != "manifest.json"
    }


def _assert_same_bytes(a: Path, b: Path) -> None:
    bytes_a, bytes_b = _object_bytes(a), _object_bytes(b)
    assert sorted(bytes_a) == sorted(bytes_b)
    differ = [name for name in bytes_a if bytes_a[name] != bytes_b[name]]
    assert differ == [], f"files whose bytes differ between {a} and {b}"
    records_a = [(f.path, f.sha256) for f in read_object(a).files]
    assert records_a == [(f.path, f.sha256) for f in read_object(b).files]


def _render_sphere(inputs: tuple[Path, Path], out: Path) -> None:
    objects, envmaps = inputs
    render_dataset(
        [("sphere", objects / "sphere.obj")],
        scan_envmaps(envmaps),
        out,
        tiny_config(lightings=3),
        RunOptions(progress=False),
    )


def test_a_second_clean_run_writes_the_same_bytes(rendered, inputs, tmp_path: Path) -> None:
    out, _ = rendered
    _render_sphere(inputs, tmp_path)
    _assert_same_bytes(out / "objects" / "sphere", tmp_path / "objects" / "sphere")
    obj = read_object(tmp_path / "objects" / "sphere")
    lit = obj.views[0].lit[0]
    import OpenEXR
    from PIL import Image

    with OpenEXR.File(str(obj.path(lit.exr))) as f:
        header = set(f.header())
    with Image.open(obj.path(lit.png)) as im:
        text = set(im.info)
    for key in header | text:
        assert key not in ("Date", "Time", "RenderTime", "File", "Frame") and not key.endswith(
            "_time"
        ), key


def test_an_interrupted_then_resumed_object_equals_a_clean_one(
    rendered, inputs, tmp_path: Path
) -> None:
    out, _ = rendered
    _render_sphere(inputs, tmp_path)
    root = tmp_path / "objects" / "sphere"
    obj = read_object(root)
    # What a kill mid-object leaves: no manifest, some images done, the rest missing, and a stale
    # temporary of the write that was under way.
    (root / "manifest.json").unlink()
    for lit in obj.views[1].lit[1:]:
        (root / lit.exr).unlink()
        (root / lit.png).unlink()
    area = obj.views[1].area
    assert area is not None and obj.views[1].alpha is not None
    for name in (area.png, area.normal, obj.views[1].alpha):
        (root / name).unlink()
    (root / "lit" / ".001_002.abcd1234.tmp.exr").write_bytes(b"partial")
    _render_sphere(inputs, tmp_path)
    _assert_same_bytes(out / "objects" / "sphere", root)


def test_rerun_skips_complete_objects_and_refuses_other_configs(rendered, inputs) -> None:
    out, _ = rendered
    objects, envmaps = inputs
    before = (out / "objects" / "cube" / "manifest.json").stat().st_mtime_ns
    summary = render_dataset(
        [("cube", objects / "cube.obj")],
        scan_envmaps(envmaps),
        out,
        tiny_config(lightings=3),
        RunOptions(progress=False),
    )
    assert summary.skipped == ("cube",) and summary.images == 0
    assert (out / "objects" / "cube" / "manifest.json").stat().st_mtime_ns == before
    with pytest.raises(ConfigError, match="different config"):
        render_dataset(
            [], scan_envmaps(envmaps), out, tiny_config(lightings=4), RunOptions(progress=False)
        )


def _cli(objects: Path, envmaps: Path, out: Path) -> list[str]:
    return [
        sys.executable, "-m", "gaffer_data.cli", "render", "--objects", str(objects), "--envmaps",
        str(envmaps), "--out", str(out), "--views", "3", "--lightings", "4", "--resolution", "32",
        "--samples", "4", "--no-denoise", "--world-map-resolution", "64", "--yaw-steps", "4",
        "--no-progress", "--retries", "1",
    ]  # fmt: skip


def _children(pid: int) -> list[int]:
    kids: list[int] = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        kids += [int(k) for k in (task / "children").read_text().split()]
    return kids


def _wait_for(predicate, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise TimeoutError("condition not reached")
        time.sleep(0.01)


def _objects_only(inputs: tuple[Path, Path], tmp_path: Path) -> Path:
    objects = tmp_path / "objects"
    write_cube_obj(objects / "cube.obj")
    write_uv_sphere_obj(objects / "sphere.obj")
    return objects


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs Linux /proc")
def test_kill_a_worker_mid_object_then_the_retry_finishes(inputs, tmp_path: Path) -> None:
    objects = _objects_only(inputs, tmp_path)
    out = tmp_path / "out"
    proc = subprocess.Popen(
        _cli(objects, inputs[1], out), stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    first = out / "objects" / "cube" / "lit" / "000_000.exr"
    _wait_for(lambda: first.exists() or proc.poll() is not None)
    for pid in _children(proc.pid):
        os.kill(pid, signal.SIGKILL)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err.decode()[-2000:]
    ds = open_dataset(out)
    assert ds.object_ids == ("cube", "sphere") and ds.failures == ()
    for obj in ds.iter_objects(verify=True):
        assert len(obj.files) == 1 + 3 * (4 * 2 + 5 + 1)
    assert not [p for p in out.rglob(".*") if is_stale_temporary(p)]


@pytest.mark.skipif(not hasattr(os, "killpg"), reason="needs process groups")
def test_kill_9_the_run_then_rerun_completes(inputs, tmp_path: Path) -> None:
    objects = _objects_only(inputs, tmp_path)
    out = tmp_path / "out"
    proc = subprocess.Popen(
        _cli(objects, inputs[1], out),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    done = out / "objects" / "cube" / "manifest.json"
    started = out / "objects" / "sphere" / "lit" / "000_000.exr"
    _wait_for(lambda: started.exists() or proc.poll() is not None)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    assert done.exists()
    before = done.stat().st_mtime_ns
    result = subprocess.run(
        _cli(objects, inputs[1], out), capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert "skipped 1 complete" in result.stdout
    assert done.stat().st_mtime_ns == before
    ds = open_dataset(out)
    assert ds.object_ids == ("cube", "sphere")
    for obj in ds.iter_objects(verify=True):
        assert len({f.path for f in obj.files}) == len(obj.files)
    assert not [p for p in out.rglob(".*") if is_stale_temporary(p)] and not list(
        out.rglob(".scratch")
    )


@pytest.mark.skipif(not hasattr(os, "killpg"), reason="needs process groups")
def test_kill_9_mid_object_then_resume_writes_the_bytes_of_a_clean_run(
    inputs, tmp_path: Path
) -> None:
    objects = _objects_only(inputs, tmp_path)
    clean, resumed = tmp_path / "clean", tmp_path / "resumed"
    result = subprocess.run(_cli(objects, inputs[1], clean), capture_output=True, timeout=300)
    assert result.returncode == 0, result.stderr.decode()[-2000:]
    proc = subprocess.Popen(
        _cli(objects, inputs[1], resumed),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    partial = resumed / "objects" / "cube" / "lit" / "001_000.exr"
    _wait_for(lambda: partial.exists() or proc.poll() is not None)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    result = subprocess.run(_cli(objects, inputs[1], resumed), capture_output=True, timeout=300)
    assert result.returncode == 0, result.stderr.decode()[-2000:]
    for name in ("cube", "sphere"):
        _assert_same_bytes(clean / "objects" / name, resumed / "objects" / name)


def test_the_worker_process_never_imports_torch(inputs, tmp_path: Path) -> None:
    from gaffer_data.render.plan import plan_object
    from gaffer_data.render.runner import PLAN_NAME, _prepare_folder

    objects, envmaps = inputs
    plan = plan_object(
        "cube", objects / "cube.obj", scan_envmaps(envmaps), tiny_config(views=1, lightings=1)
    )
    _prepare_folder(plan, tmp_path)
    code = (
        "import sys\nfrom gaffer_data.render import worker\n"
        "code = worker.main(['--job', sys.argv[1], '--threads', '1'])\n"
        "loaded = sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'pymeshlab'))\n"
        "print('CHECK', code, 'gaffer_envmap.augment' in sys.modules, loaded)\n"
    )
    result = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path / PLAN_NAME)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    line = next(x for x in result.stdout.splitlines() if x.startswith("CHECK"))
    assert line == "CHECK 0 True []", result.stderr[-2000:]
    assert (tmp_path / plan.views[0].lit[0].exr).is_file()


def test_two_runs_into_one_folder_share_the_objects(inputs, tmp_path: Path, caplog) -> None:
    import logging
    import threading

    pytest.importorskip("fcntl")
    objects, envmaps = inputs
    todo = [(n, objects / f"{n}.obj") for n in ("cube", "sphere")]
    summaries: list = []

    def run() -> None:
        summaries.append(
            render_dataset(
                todo,
                scan_envmaps(envmaps),
                tmp_path,
                tiny_config(lightings=2),
                RunOptions(workers=1, retries=0, progress=False),
            )
        )

    caplog.set_level(logging.WARNING, logger="gaffer_data")
    threads = [threading.Thread(target=run) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(summaries) == 2
    # every failure is a "busy" hand-over, never a clash inside an object's folder
    assert all(f.reason.startswith("busy") for s in summaries for f in s.failed)
    assert not [r for r in caplog.records if "attempt" in r.getMessage()]
    for name, _ in todo:
        read_object(tmp_path / "objects" / name)  # complete and valid
    assert [o.object_id for o in open_dataset(tmp_path).iter_objects()] == ["cube", "sphere"]
