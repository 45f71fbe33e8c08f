"""`relight`, `insert` and `evaluate` build one typed request from their arguments (`cli._from_args`):
each input file is read once per call however many frames or outputs use it, the command bodies take
the request, and each refusal is written once in the command line's source."""

import argparse
import ast
import collections
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import gaffer_diffusion.cli as cli_package
from gaffer_diffusion.cli import _parser, main
from gaffer_diffusion.cli._from_args import evaluate_request, insert_request, relight_request
from gaffer_diffusion.cli._requests import (
    EncodedLight,
    EnvmapLight,
    EvaluateFoldersRequest,
    InsertRequest,
    RelightRequest,
)
from gaffer_diffusion.errors import ConfigError


def _photo(path: Path, shade: int = 90) -> Path:
    a = np.zeros((40, 30, 4), np.uint8)
    a[..., :3] = shade
    a[8:30, 5:25, 3] = 255
    Image.fromarray(a).save(path)
    return path


def _w2c(path: Path) -> Path:
    np.save(path, np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, -2.5]], float))
    return path


class _Reads:
    """Counts the reads of each file by the readers the command line calls."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        import gaffer_diffusion.photo
        import gaffer_diffusion.suggested
        import gaffer_envmap.io

        self.counts: collections.Counter[str] = collections.Counter()
        for module, name in (
            (gaffer_envmap.io, "read_envmap"),
            (gaffer_diffusion.photo, "read_photo"),
            (gaffer_diffusion.suggested, "read_default_sampling"),
            (np, "load"),
        ):
            monkeypatch.setattr(module, name, self._counted(getattr(module, name), name))

    def _counted(self, real, name: str):
        def read(path, *a, **k):
            # the model's sampling is counted where the command line reads it (the loader reads
            # the manifest of the folder it loads on its own)
            caller = sys._getframe(1).f_globals.get("__name__", "")
            mine = name != "read_default_sampling" or caller.startswith("gaffer_diffusion.cli")
            if isinstance(path, str | Path) and mine:
                self.counts[f"{name} {Path(path).name}"] += 1
            return real(path, *a, **k)

        return read


def test_a_turntable_reads_its_map_photo_and_camera_once(tmp_path, monkeypatch, capsys) -> None:
    from gaffer_envmap import bundled_hdris

    reads = _Reads(monkeypatch)
    envmap = Path(bundled_hdris()["studio"])
    argv = ["relight", str(_photo(tmp_path / "obj.png")), "--envmap", str(envmap)]
    argv += ["--w2c", str(_w2c(tmp_path / "cam.npy")), "--turntable", "4", "--video", "gif"]
    argv += ["--background", "envmap", "--out", str(tmp_path / "t.png")]
    assert main(argv) == 0, capsys.readouterr().err
    # 4 frames, each encoded and each given the map as its backdrop: still one read of each file
    assert reads.counts == {
        f"read_envmap {envmap.name}": 1,
        "read_photo obj.png": 1,
        "load cam.npy": 1,
        f"read_default_sampling {reads_tiny_folder()}": 1,
    }, reads.counts
    frames = [f"t_{k:03d}.png" for k in range(4)]
    assert sorted(p.name for p in tmp_path.glob("t*")) == sorted([*frames, "t.gif"])


def reads_tiny_folder() -> str:
    from gaffer_diffusion import pretrained

    return Path(pretrained.gaffer_tiny_path()).name


def test_a_grid_reads_each_map_and_each_photo_once(tmp_path, monkeypatch, capsys) -> None:
    from gaffer_envmap import EnvironmentMap, write_envmap

    maps = tmp_path / "maps"
    maps.mkdir()
    for k, name in enumerate(("a", "b")):
        env = np.full((8, 16, 3), 0.3 + 0.4 * k, np.float32)
        write_envmap(maps / f"{name}.exr", EnvironmentMap(radiance_linear=env))
    imgs = tmp_path / "imgs"
    imgs.mkdir()
    for k in range(2):
        _photo(imgs / f"p{k}.png", 40 + 80 * k)
    reads = _Reads(monkeypatch)
    argv = ["relight", str(imgs), "--envmaps", str(maps), "--azimuth", "20", "--elevation", "5"]
    argv += ["--background", "envmap", "--out", str(tmp_path / "o")]
    assert main(argv) == 0, capsys.readouterr().err
    assert {k: v for k, v in reads.counts.items() if not k.startswith("read_default")} == {
        "read_envmap a.exr": 1,
        "read_envmap b.exr": 1,
        "read_photo p0.png": 1,
        "read_photo p1.png": 1,
    }, reads.counts
    assert len(list((tmp_path / "o").rglob("*.png"))) == 4


def test_insert_reads_its_map_camera_and_photos_once(tmp_path, monkeypatch, capsys) -> None:
    from gaffer_envmap import bundled_hdris

    Image.fromarray(np.full((90, 130, 3), 120, np.uint8)).save(tmp_path / "bg.png")
    reads = _Reads(monkeypatch)
    envmap = Path(bundled_hdris()["city"])
    argv = ["insert", str(_photo(tmp_path / "obj.png")), "--into", str(tmp_path / "bg.png")]
    argv += ["--envmap", str(envmap), "--w2c", str(_w2c(tmp_path / "cam.npy"))]
    argv += ["--out", str(tmp_path / "i.png")]
    assert main(argv) == 0, capsys.readouterr().err
    assert {k: v for k, v in reads.counts.items() if not k.startswith("read_default")} == {
        f"read_envmap {envmap.name}": 1,
        "read_photo obj.png": 1,
        "read_photo bg.png": 1,
        "load cam.npy": 1,
    }, reads.counts


def test_the_requests_hold_what_was_read(tmp_path) -> None:
    from gaffer_envmap import bundled_hdris

    photo = _photo(tmp_path / "obj.png")
    args = _parser().parse_args(
        [
            "relight",
            str(photo),
            "--envmap",
            "city",
            "--azimuth",
            "30",
            "--elevation",
            "10",
            "--steps",
            "3",
            "--compat",
            "neural-gaffer",
            "--out",
            str(tmp_path / "o.png"),
        ]
    )
    request = relight_request(args)
    assert isinstance(request, RelightRequest) and not request.grid
    (light,) = request.lights
    assert isinstance(light, EnvmapLight) and light.path == Path(bundled_hdris()["city"])
    assert light.env.radiance_linear.shape[1] == 2 * light.env.radiance_linear.shape[0]
    assert request.photos[0][0] == photo and request.photos[0][1].alpha.shape == (40, 30)
    model = request.model
    assert model.compat == "neural-gaffer" and model.latent_mode == "sample"
    assert model.sampling_config().num_inference_steps == 3
    with pytest.raises(AttributeError):  # frozen
        request.turntable = 3  # type: ignore[misc]
    encoded = relight_request(
        _parser().parse_args(
            [
                "relight",
                str(photo),
                "--ldr",
                str(photo),
                "--hdr",
                str(photo),
                "--out",
                str(tmp_path / "e.png"),
            ]
        )
    )
    assert encoded.lights == (EncodedLight(ldr=photo, hdr=photo),)
    bg = tmp_path / "bg.png"
    Image.fromarray(np.full((90, 130, 3), 120, np.uint8)).save(bg)
    ins = insert_request(
        _parser().parse_args(
            [
                "insert",
                str(photo),
                "--into",
                str(bg),
                "--key-light",
                "90,30",
                "--out",
                str(tmp_path / "i.png"),
            ]
        )
    )
    assert isinstance(ins, InsertRequest) and ins.background.size_wh == (130, 90)
    assert ins.lighting.key_light is not None and ins.lighting.key_light.azimuth_deg == 90.0
    folders = evaluate_request(
        _parser().parse_args(["evaluate", "--pred", str(tmp_path), "--gt", str(tmp_path)])
    )
    assert isinstance(folders, EvaluateFoldersRequest)
    assert folders.names == ("bg.png", "obj.png") and folders.masks is None
    assert folders.reports.perceptual == "auto"


def test_a_request_is_refused_before_it_is_built(tmp_path) -> None:
    photo = _photo(tmp_path / "obj.png")
    args = _parser().parse_args(
        [
            "relight",
            str(photo),
            "--ldr",
            str(photo),
            "--hdr",
            str(photo),
            "--turntable",
            "3",
            "--out",
            str(tmp_path / "o.png"),
        ]
    )
    with pytest.raises(ConfigError, match="`--turntable` needs `--envmap`"):
        relight_request(args)
    args = argparse.Namespace(**{**vars(args), "turntable": 0, "hdr": None})
    with pytest.raises(ConfigError, match="Pass both `--ldr` and `--hdr`"):
        relight_request(args)


def _raised_texts(path: Path) -> list[str]:
    """The message of every `raise SomeError(<text>)` in a module, as written in the source."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    texts = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Raise) and isinstance(node.exc, ast.Call) and node.exc.args:
            arg = node.exc.args[0]
            if isinstance(arg, ast.Constant | ast.JoinedStr):
                texts.append(ast.unparse(arg))
    return texts


def test_each_refusal_is_written_once() -> None:
    cli_dir = Path(cli_package.__file__).parent
    files = [*sorted(cli_dir.glob("*.py")), cli_dir.parent / "_cli_checks.py"]
    where: dict[str, list[str]] = collections.defaultdict(list)
    for f in files:
        for text in _raised_texts(f):
            where[text].append(f.name)
    repeated = {t: w for t, w in where.items() if len(w) > 1}
    assert not repeated, repeated
    # the MP4 refusal is the writer's own text, named (not copied) by the relight checks
    video = (cli_dir.parent / "_video.py").read_text(encoding="utf-8")
    needle = "needs an MP4 encoder"
    assert video.count(needle) == 1
    assert not any(needle in f.read_text(encoding="utf-8") for f in files)
