"""A `gaffer-diffusion app` server on a free local port, shared by the app tests of one session.

The server runs in its own process, as a user starts it (`python -m gaffer_diffusion.cli app`), with
its own TMPDIR, so the tests can check what it leaves behind.
"""

import os
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

STARTUP_TIMEOUT_S = 180.0
"""Importing torch + Gradio and loading gaffer-tiny on a busy 2-core CI machine."""

MAX_IMAGE_SIDE = 1024
"""The server's `--max-image-side` in these tests (small, so the refusal is cheap to trigger)."""

MAX_UPLOAD_MB = 1.0
"""The server's `--max-upload-mb` in these tests."""


@dataclass(frozen=True, kw_only=True)
class AppServer:
    """A running app: its URL, process, TMPDIR, log file and the limits it was started with."""

    url: str
    process: subprocess.Popen[bytes]
    tmpdir: Path
    log: Path
    max_image_side: int = 4096
    max_upload_mb: float = 20.0

    def log_text(self) -> str:
        return self.log.read_text(errors="replace")


def free_port() -> int:
    """A TCP port nothing listens on right now (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _wait_until_up(url: str, process: subprocess.Popen[bytes], log: Path) -> None:
    """Poll the page until it answers, failing early (with the log) when the server exits."""
    deadline = time.monotonic() + STARTUP_TIMEOUT_S
    while time.monotonic() < deadline:
        if process.poll() is not None:
            pytest.fail(f"the app exited with {process.returncode}:\n{log.read_text()[-4000:]}")
        try:
            with urllib.request.urlopen(url, timeout=2) as response:
                if response.status == 200:
                    return
        except (urllib.error.URLError, ConnectionError, TimeoutError):
            pass
        time.sleep(0.25)  # a readiness poll with a deadline, not a fixed wait
    process.kill()
    pytest.fail(f"the app did not answer within {STARTUP_TIMEOUT_S} s:\n{log.read_text()[-4000:]}")


def start_app(tmp: Path, *extra: str, **limits: Any) -> AppServer:
    """Start `gaffer-diffusion app` on a free port with its own TMPDIR; returns once it answers."""
    port = free_port()
    tmpdir = tmp / "tmp"
    tmpdir.mkdir(parents=True)
    log = tmp / "app.log"
    env = {**os.environ, "TMPDIR": str(tmpdir), "OMP_NUM_THREADS": "1"}
    env.pop("GRADIO_ANALYTICS_ENABLED", None)  # the app must switch analytics off by itself
    cmd = [
        sys.executable,
        "-m",
        "gaffer_diffusion.cli",
        "app",
        "--port",
        str(port),
        "--threads",
        "1",
    ]
    with log.open("wb") as out:
        process = subprocess.Popen(
            [*cmd, *extra], stdout=out, stderr=subprocess.STDOUT, env=env, cwd=tmp
        )
    url = f"http://127.0.0.1:{port}/"
    _wait_until_up(url, process, log)
    return AppServer(url=url, process=process, tmpdir=tmpdir, log=log, **limits)


def stop_app(server: AppServer) -> int:
    """SIGTERM, as a service manager stops it; returns the exit status."""
    server.process.terminate()
    try:
        return server.process.wait(timeout=30)
    except subprocess.TimeoutExpired:
        server.process.kill()
        raise


@pytest.fixture(scope="session")
def start_app_fn() -> Any:
    """`start_app` and `stop_app` for tests that need a server of their own."""
    return start_app, stop_app


@pytest.fixture(scope="session")
def app_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[AppServer]:
    """One app for the session's app tests (small limits, so the refusals are quick to provoke)."""
    pytest.importorskip(
        "gradio", reason='the app tests need the app extra: pip install "gaffer-diffusion[app]"'
    )
    pytest.importorskip("gradio_client", reason="the app tests drive the app with gradio_client")
    server = start_app(
        tmp_path_factory.mktemp("app"),
        "--max-image-side",
        str(MAX_IMAGE_SIDE),
        "--max-upload-mb",
        str(MAX_UPLOAD_MB),
        "--max-frames",
        "8",
        max_image_side=MAX_IMAGE_SIDE,
        max_upload_mb=MAX_UPLOAD_MB,
    )
    yield server
    if server.process.poll() is None:
        stop_app(server)
