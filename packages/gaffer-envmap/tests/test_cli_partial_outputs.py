"""Multi-file outputs of `gaffer-envmap` are complete or absent."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from gaffer_envmap import cli, write_envmap
from gaffer_envmap.atomic import atomic_files
from gaffer_envmap.cli import main
from gaffer_envmap.testing import disc_sun_map


@pytest.fixture
def sky(tmp_path: Path) -> Path:
    src = tmp_path / "sky.exr"
    write_envmap(src, disc_sun_map(32, np.array([0.0, 1.0, 0.5]), 5.0, 500.0, sky=0.3))
    return src


def _failing_after(n: int, exc: BaseException):
    real = cli.write_envmap
    calls = {"n": 0}

    def write(path, *a, **k):
        calls["n"] += 1
        if calls["n"] > n:
            raise exc
        return real(path, *a, **k)

    return write


@pytest.mark.parametrize("exc", [OSError(28, "No space left on device"), KeyboardInterrupt()])
def test_augment_failing_midway_leaves_no_new_folder(
    sky: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, exc: BaseException
) -> None:
    out = tmp_path / "pool"
    monkeypatch.setattr(cli, "write_envmap", _failing_after(5, exc))
    code = main(["augment", str(sky), "--out-dir", str(out), "--flips", "--yaw-steps", "8"])
    assert code != 0
    assert not out.exists()


def test_augment_failing_midway_keeps_an_earlier_complete_pool(
    sky: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "pool"
    assert main(["augment", str(sky), "--out-dir", str(out), "--yaw-steps", "4"]) == 0
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    monkeypatch.setattr(cli, "write_envmap", _failing_after(3, OSError(28, "disk full")))
    assert main(["augment", str(sky), "--out-dir", str(out), "--flips", "--yaw-steps", "8"]) != 0
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_procedural_failing_midway_writes_nothing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "proc"
    monkeypatch.setattr(cli, "write_envmap", _failing_after(2, OSError(28, "disk full")))
    assert main(["procedural", "--out-dir", str(out), "--count", "5", "--height", "8"]) != 0
    assert not out.exists()


def test_atomic_files_moves_nothing_when_the_block_raises(tmp_path: Path) -> None:
    (tmp_path / "keep.txt").write_text("old")
    with pytest.raises(RuntimeError), atomic_files(tmp_path) as stage:
        (stage / "keep.txt").write_text("new")
        raise RuntimeError("boom")
    assert [p.name for p in tmp_path.iterdir()] == ["keep.txt"]
    assert (tmp_path / "keep.txt").read_text() == "old"


@pytest.mark.skipif(os.name != "posix", reason="SIGKILL")
def test_augment_killed_mid_run_leaves_no_final_named_file(tmp_path: Path) -> None:
    out = tmp_path / "pool"
    out.mkdir()
    sky = tmp_path / "big.exr"
    write_envmap(sky, disc_sun_map(256, np.array([0.0, 1.0, 0.5]), 5.0, 500.0, sky=0.3))
    # 1024 maps of 256 rows: long enough to be caught in the middle
    log = tmp_path / "augment.stderr"  # a file, not a pipe: a full pipe would stall the writer
    with log.open("wb") as err:
        proc = subprocess.Popen(
            [
                *(sys.executable, "-m", "gaffer_envmap.cli", "augment", str(sky)),
                *("--out-dir", str(out), "--flips", "--yaw-steps", "512"),
            ],
            stdout=subprocess.DEVNULL,
            stderr=err,
        )
    deadline = time.monotonic() + 120
    staged = 0
    while time.monotonic() < deadline and proc.poll() is None:
        stages = list(out.glob(".partial-*"))
        staged = sum(1 for s in stages for _ in s.glob("*.exr"))
        if staged >= 3:
            break
        time.sleep(0.02)
    # this used to skip, so a crash at start-up read as a skip. Writing 1024 maps takes
    # far longer than the 20 ms poll that sees the third staged file, so an exit here is a failure.
    rc = proc.poll()
    assert rc is None, f"augment exited with {rc} before it could be killed:\n{log.read_text()}"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert staged >= 3
    assert list(out.glob("*.exr")) == []  # only the hidden staging folder may remain


@pytest.mark.parametrize("exc", [OSError(28, "No space left on device"), KeyboardInterrupt()])
def test_encode_failing_on_the_second_png_keeps_both_earlier_pngs(
    sky: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, exc: BaseException
) -> None:
    # `encode` replaced ldr.png, then failed on hdr.png; now both are written or neither
    np.save(tmp_path / "w2c.npy", np.concatenate([np.eye(3), [[0.0], [0.0], [-2.0]]], axis=1))
    out = tmp_path / "enc"
    out.mkdir()
    (out / "ldr.png").write_bytes(b"old ldr")
    (out / "hdr.png").write_bytes(b"old hdr")
    real, calls = cli.write_png, {"n": 0}

    def write_png(path, *a, **k):
        calls["n"] += 1
        if calls["n"] > 1:
            raise exc
        return real(path, *a, **k)

    monkeypatch.setattr(cli, "write_png", write_png)
    argv = ["encode", str(sky), "--w2c", str(tmp_path / "w2c.npy"), "--out-dir", str(out)]
    assert main([*argv, "--size", "16"]) in (2, 130)
    assert calls["n"] == 2
    assert (out / "ldr.png").read_bytes() == b"old ldr"
    assert (out / "hdr.png").read_bytes() == b"old hdr"
    assert sorted(p.name for p in out.iterdir()) == ["hdr.png", "ldr.png"]  # no staging left


def test_encode_into_a_new_folder_failing_leaves_no_folder(
    sky: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    np.save(tmp_path / "w2c.npy", np.concatenate([np.eye(3), [[0.0], [0.0], [-2.0]]], axis=1))
    real, calls = cli.write_png, {"n": 0}

    def write_png(path, *a, **k):
        calls["n"] += 1
        if calls["n"] > 1:
            raise OSError(28, "No space left on device")
        return real(path, *a, **k)

    monkeypatch.setattr(cli, "write_png", write_png)
    out = tmp_path / "new"
    argv = ["encode", str(sky), "--w2c", str(tmp_path / "w2c.npy"), "--out-dir", str(out)]
    assert main([*argv, "--size", "16"]) == 2
    assert not out.exists()


def test_a_refusal_comes_before_torch_is_imported(tmp_path: Path) -> None:
    # the CLI imports the torch-backed rotate/encode only once the inputs are good
    code = (
        "import sys; from gaffer_envmap.cli import main; "
        "rc = main(['rotate', 'missing.exr', 'o.exr', '--w2c', 'missing.npy']); "
        "print(rc, 'torch' in sys.modules)"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, check=False
    )
    assert done.stdout.split() == ["2", "False"], done.stdout + done.stderr
    assert list(tmp_path.iterdir()) == []
