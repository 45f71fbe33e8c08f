"""kill -9 in the middle of a multi-file output leaves the earlier run's files as they were (issue 17).

The demo builds its whole folder in a hidden `.OUT.partial-*` sibling and renames it into place at the
end (`gaffer_diffusion._atomic_dir`). A SIGKILL cannot be caught, so the only guarantee is structural:
nothing is written under the final names before the rename. These tests kill a real `gaffer-diffusion
demo` process once its staging folder holds files, and check that the earlier run's folder is byte
for byte what it was, with no new file beside it.
"""

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("gaffer_diffusion")
pytest.importorskip("torch")

TIMEOUT_S = 240.0


def _digests(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _staged_files(parent: Path, name: str) -> list[Path]:
    return [p for d in parent.glob(f".{name}.partial-*") for p in d.rglob("*") if p.is_file()]


@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs POSIX signals")
def test_demo_killed_mid_run_leaves_the_earlier_folder_untouched(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    out.mkdir()
    # an earlier run's outputs (and a file another tool put there)
    (out / "report.html").write_text("<html>earlier run</html>")
    (out / "metrics.json").write_text('{"earlier": true}')
    (out / "overview.png").write_bytes(b"\x89PNG earlier")
    (out / "notes.txt").write_text("mine, not the demo's")
    before = _digests(out)
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONHASHSEED": "0"}
    log = tmp_path / "stderr.txt"
    with log.open("wb") as err_file:
        proc = subprocess.Popen(
            [sys.executable, "-m", "gaffer_diffusion.cli", "demo", "--out", str(out)],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=err_file,
        )
    try:
        deadline = time.monotonic() + TIMEOUT_S
        while time.monotonic() < deadline and proc.poll() is None:
            if _staged_files(tmp_path, "demo"):
                break
            time.sleep(0.05)
        if proc.poll() is not None:
            err = log.read_text(errors="replace")
            pytest.fail(f"the demo ended (exit {proc.returncode}) before it was killed: {err}")
        assert _staged_files(tmp_path, "demo"), "the demo wrote no staged file in time"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == -signal.SIGKILL
    # the earlier folder: the same files, the same bytes, nothing new under the final names
    assert _digests(out) == before
    # what the kill can leave: only the hidden staging sibling
    leftovers = {
        p.name.split("-")[0] for p in tmp_path.iterdir() if p.name not in ("demo", log.name)
    }
    assert leftovers <= {".demo.partial"}
