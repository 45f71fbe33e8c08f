"""`gaffer-diffusion app` under stress, through gradio_client against a real server:

- a burst of concurrent requests: the good ones answered, those beyond the bounded queue refused at
  once in one line ("Queue is full"), nothing buffered without bound;
- a client killed mid-job: the server finishes or drops the job and keeps answering others;
- a huge image: one over `--max-image-megapixels`, and a decompression bomb (a PNG whose header says
  60000x60000), refused in one line without decoding; the server's peak memory stays bounded;
- temporary files: uploads and results older than `--cache-max-age` are deleted while the server runs,
  and the server's folder is gone when it stops.
"""

import os
import struct
import subprocess
import sys
import textwrap
import threading
import time
import zlib
from pathlib import Path
from typing import Any

import pytest
from PIL import Image

pytestmark = pytest.mark.slow

TINY = "gaffer-tiny (shipped)"
QUEUE_SIZE = 2
MAX_MEGAPIXELS = 1.0
CACHE_MAX_AGE_S = 8
MAX_PEAK_RSS_MB = 3000
"""Generous bound on the server's peak resident memory over this module (gaffer-tiny on CPU)."""


@pytest.fixture(scope="module")
def server(start_app_fn: Any, tmp_path_factory: pytest.TempPathFactory) -> Any:
    pytest.importorskip("gradio")
    pytest.importorskip("gradio_client")
    start, stop = start_app_fn
    srv = start(
        tmp_path_factory.mktemp("stress"),
        "--queue-size",
        str(QUEUE_SIZE),
        "--max-image-side",
        "2048",
        "--max-image-megapixels",
        str(MAX_MEGAPIXELS),
        "--cache-max-age",
        str(CACHE_MAX_AGE_S),
        "--max-frames",
        "8",
    )
    yield srv
    if srv.process.poll() is None:
        stop(srv)


@pytest.fixture(scope="module")
def photo() -> Path:
    from gaffer_diffusion.pretrained import example_dataset_path

    obj = sorted((example_dataset_path() / "objects").iterdir())[0]
    return obj / "lit" / "000_000.png"


def _client(server: Any, tmp: Path) -> Any:
    from gradio_client import Client

    return Client(server.url, verbose=False, download_files=str(tmp))


def _job(photo: Path) -> list[Any]:
    from gradio_client import handle_file

    return [TINY, handle_file(str(photo)), None, "sunset", None, 30.0, 10.0, 0.0, None, 0, "model"]


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    assert "\n" not in text and "Traceback" not in text, text
    return text


def _peak_rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise AssertionError("no VmHWM")


def test_a_burst_beyond_the_queue_is_answered_or_refused(
    server: Any, photo: Path, tmp_path: Path
) -> None:
    client = _client(server, tmp_path)
    n = 10
    results: list[Any] = [None] * n

    def send(i: int) -> None:
        try:
            results[i] = client.predict(*_job(photo), api_name="/relight")
        except Exception as exc:  # the refusal, checked below
            results[i] = exc

    threads = [threading.Thread(target=send, args=(i,)) for i in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert not any(t.is_alive() for t in threads), "a request was never answered"
    answered = [r for r in results if not isinstance(r, BaseException)]
    refused = [r for r in results if isinstance(r, BaseException)]
    assert len(answered) >= 1 + QUEUE_SIZE  # the running job and the queued ones
    for r in answered:  # each answer carries its relit image
        assert any(isinstance(x, str) and x.endswith(".png") and Path(x).is_file() for x in r), r
    assert refused, "10 requests at once never filled a queue of 2"
    for exc in refused:
        assert "queue is full" in _one_line(exc).lower()
    # the server is still there and answers the next request
    assert client.predict(*_job(photo), api_name="/relight") is not None


_KILLED_CLIENT = textwrap.dedent(
    """
    import sys, time
    from gradio_client import Client, handle_file
    from gradio_client.utils import Status
    client = Client(sys.argv[1], verbose=False)
    job = client.submit(
        "gaffer-tiny (shipped)", handle_file(sys.argv[2]), None, "sunset", None, 30.0, 10.0, 0.0,
        None, 0, "photo", 8, 8, api_name="/turntable",
    )
    while job.status().code != Status.PROCESSING:
        time.sleep(0.02)
    print("processing", flush=True)
    time.sleep(600)
    """
)


def test_a_client_killed_mid_job_does_not_wedge_the_server(
    server: Any, photo: Path, tmp_path: Path
) -> None:
    script = tmp_path / "client.py"
    script.write_text(_KILLED_CLIENT)
    proc = subprocess.Popen(
        [sys.executable, str(script), server.url, str(photo)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert line.strip() == "processing", line + proc.stdout.read()[-2000:]
    finally:
        proc.kill()  # the client vanishes while its turntable samples
        proc.wait()
        if proc.stdout is not None:
            proc.stdout.close()
    client = _client(server, tmp_path)
    t0 = time.monotonic()
    out = client.predict(*_job(photo), api_name="/relight")
    assert out is not None and time.monotonic() - t0 < 180
    assert server.process.poll() is None


def _png_header_only(path: Path, width: int, height: int) -> Path:
    """A valid PNG signature and IHDR for a `width` x `height` RGBA image, one tiny IDAT: a few hundred
    bytes that would decode to width * height * 4 bytes (a decompression bomb)."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = zlib.crc32(kind + data) & 0xFFFFFFFF
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0)
    idat = zlib.compress(b"\0" * 1024)
    path.write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")
    )
    return path


def test_huge_images_are_refused_in_one_line(server: Any, tmp_path: Path) -> None:
    from gradio_client.exceptions import AppError

    client = _client(server, tmp_path)
    big = tmp_path / "big.png"
    Image.new("RGBA", (1200, 1000), (200, 30, 30, 255)).save(big)  # 1.2 MP, sides under 2048
    with pytest.raises(AppError) as info:
        client.predict(*_job(big), api_name="/relight")
    text = _one_line(info.value)
    assert "1200x1000" in text and "--max-image-megapixels" in text

    bomb = _png_header_only(tmp_path / "bomb.png", 60000, 60000)
    assert bomb.stat().st_size < 10_000
    with pytest.raises(AppError) as info:
        client.predict(*_job(bomb), api_name="/relight")
    text = _one_line(info.value)
    assert "60000x60000" in text and "--max-image-side" in text, text
    assert str(server.tmpdir) not in text  # no server paths
    assert server.process.poll() is None
    peak = _peak_rss_mb(server.process.pid)
    assert peak < MAX_PEAK_RSS_MB, f"the server peaked at {peak:.0f} MB"


def test_temporary_files_are_removed(
    server: Any, photo: Path, tmp_path: Path, start_app_fn: Any
) -> None:
    client = _client(server, tmp_path)
    client.predict(*_job(photo), api_name="/relight")
    (root,) = server.tmpdir.glob("gaffer-app-*")
    cache = root / "gradio"

    def files() -> list[Path]:
        return [p for p in cache.rglob("*") if p.is_file()]

    assert files(), "the request left nothing in Gradio's cache to check"
    made = {p: p.stat().st_ctime for p in files()}
    deadline = time.monotonic() + CACHE_MAX_AGE_S + 30
    while time.monotonic() < deadline and any(p.exists() for p in made):
        time.sleep(0.5)
    assert not any(p.exists() for p in made), "files older than --cache-max-age were kept"
    _, stop = start_app_fn
    assert stop(server) == 0
    assert not list(server.tmpdir.iterdir()), os.listdir(server.tmpdir)
