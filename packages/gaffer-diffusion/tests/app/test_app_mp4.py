"""The turntable's MP4: written atomically with whatever encoder this machine has, and without one
the page hides its MP4 button and says why (the GIF stays)."""

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from gaffer_diffusion.errors import MissingDependencyError


def _frames(n: int = 3, h: int = 33, w: int = 47) -> list[np.ndarray]:
    # odd sides on purpose: H.264's yuv420p needs even ones, the writer pads
    return [np.full((h, w, 3), 40 * k, np.uint8) for k in range(n)]


def test_mp4_is_written_atomically(tmp_path: Path) -> None:
    from gaffer_diffusion.app.engine import is_mp4, mp4_backend, write_mp4

    if mp4_backend() is None:
        pytest.skip("no MP4 encoder here (ffmpeg, PyAV or OpenCV)")
    out = write_mp4(tmp_path / "turntable.mp4", _frames(), 8.0)
    assert out == tmp_path / "turntable.mp4" and is_mp4(out)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["turntable.mp4"]  # no partial file left


def test_without_an_encoder_there_is_no_mp4(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from gaffer_diffusion.app import engine

    monkeypatch.setattr(engine, "mp4_backend", lambda: None)
    with pytest.raises(MissingDependencyError, match="MP4 needs an encoder"):
        engine.write_mp4(tmp_path / "turntable.mp4", _frames(), 8.0)
    assert list(tmp_path.iterdir()) == []


_PAGE_SCRIPT = """
import json, os, sys
from pathlib import Path
os.environ["GRADIO_ANALYTICS_ENABLED"] = "False"
from gaffer_diffusion.app import _ui
from gaffer_diffusion.app.config import AppConfig
from gaffer_diffusion.app.engine import Engine
_ui.mp4_backend = lambda: None if sys.argv[1] == "none" else sys.argv[1]
demo = _ui.build_app(Engine(AppConfig()), Path(sys.argv[2]))
found = {b.elem_id: b for b in demo.blocks.values() if getattr(b, "elem_id", None)}
print(json.dumps({k: [found[k].visible, str(getattr(found[k], "value", ""))]
                  for k in ("download_mp4", "download_gif", "mp4_note")}))
"""


def _page(tmp_path: Path, backend: str) -> dict[str, Any]:
    """The page's MP4 widgets when `mp4_backend()` says `backend` (built in its own process, as the
    server builds it: Gradio's helper threads and loops stay out of this test process)."""
    env = {
        **os.environ,
        "GRADIO_TEMP_DIR": str(tmp_path / "gradio"),
        "OMP_NUM_THREADS": "1",
        "TMPDIR": str(tmp_path),
    }
    done = subprocess.run(
        [sys.executable, "-c", _PAGE_SCRIPT, backend, str(tmp_path / "jobs")],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_page_hides_the_mp4_button_and_says_why(tmp_path: Path) -> None:
    pytest.importorskip(
        "gradio", reason='the app tests need the app extra: pip install "gaffer-diffusion[app]"'
    )
    from gaffer_diffusion.app.engine import MP4_UNAVAILABLE

    page = _page(tmp_path, "none")
    assert page["download_mp4"][0] is False
    assert page["download_gif"][0] is not False
    assert page["mp4_note"][0] is True and MP4_UNAVAILABLE in page["mp4_note"][1]
    page = _page(tmp_path, "opencv")
    assert page["download_mp4"][0] is True and page["mp4_note"][0] is False
