"""Bad `gaffer-nerf` arguments are refused in one line before torch is imported."""

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from gaffer_nerf.cli import main


def _fake_field(folder: Path) -> Path:
    """A field folder whose files parse (the real tensors are never needed before the checks)."""
    folder.mkdir(parents=True)
    (folder / "config.json").write_text(json.dumps({"_class_name": "TensoRFVM"}))
    header = json.dumps({"w": {"dtype": "F32", "shape": [1], "data_offsets": [0, 4]}}).encode()
    (folder / "field.safetensors").write_bytes(
        len(header).to_bytes(8, "little") + header + bytes(4)
    )
    return folder


def _fake_data(folder: Path, *, test: bool = True) -> Path:
    folder.mkdir(parents=True)
    meta = {
        "frames": [{"file_path": "x", "lit": [{"lighting_index": 0, "file_path": "x"}]}],
        "lightings": [{"lighting_index": 0, "envmap": "a"}, {"lighting_index": 1, "envmap": "b"}],
    }
    (folder / "transforms_train.json").write_text(json.dumps(meta))
    if test:
        (folder / "transforms_test.json").write_text(json.dumps(meta))
    return folder


@pytest.fixture
def paths(tmp_path: Path) -> dict[str, str]:
    field, data = _fake_field(tmp_path / "field"), _fake_data(tmp_path / "data")
    notest = _fake_data(tmp_path / "notest", test=False)
    (tmp_path / "afile").write_text("x")
    (tmp_path / "notjson").mkdir()
    (tmp_path / "notjson" / "transforms_train.json").write_text("{not json")
    bad = _fake_field(tmp_path / "badfield")
    (bad / "field.safetensors").write_bytes(b"\x10\x00\x00\x00\x00\x00\x00\x00{trunc")
    badcfg = _fake_field(tmp_path / "badcfg")
    (badcfg / "config.json").write_text("[1, 2")
    slots = tmp_path / "slots"  # a folder in each file's place
    for name in ("field.safetensors", "000.png", "orbit.gif"):
        (slots / name).mkdir(parents=True)
    (tmp_path / "views_file").mkdir()
    (tmp_path / "views_file" / "relit_views").write_text("a file where relit_views/ goes")
    return {
        "slots": str(slots),
        "views_file": str(tmp_path / "views_file"),
        "field": str(field),
        "data": str(data),
        "notest": str(notest),
        "out": str(tmp_path / "out"),
        "file": str(tmp_path / "afile"),
        "under_file": str(tmp_path / "afile" / "out"),
        "notjson": str(tmp_path / "notjson"),
        "badfield": str(bad),
        "badcfg": str(badcfg),
        "missing": str(tmp_path / "missing"),
        "tmp": str(tmp_path),
    }


RL = "relight {field} --data {data} --out {out}"
CASES = [
    ("fit {missing} --out {out}", "transforms_train.json does not exist"),
    ("fit {notjson} --out {out}", "is not valid JSON"),
    ("fit {data} --out {out} --iterations 0", "`--iterations` is 0"),
    ("fit {data} --out {out} --batch-rays 100000000", "GiB for one step"),
    ("fit {data} --out {out} --batch-rays 0", "`--batch-rays` is 0"),
    ("fit {data} --out {out} --lighting-index 5", "`--lighting-index` is 5"),
    ("fit {data} --out {file}", "is a file, not a folder; pass a folder"),
    ("fit {data} --out {under_file}", "is a file, not a folder"),
    ("fit {data} --out {out} --device gpu", "`--device` is 'gpu'"),
    ("fit {notest} --out {out} --early-stopping", "transforms_test.json"),
    ("fit {data} --out {out} --rank-ladder 1 0.5", "strictly increasing"),
    (RL + " --target-lighting 1 --stage1-iterations 0", "`--stage1-iterations` is 0"),
    (RL + " --target-lighting 1 --steps 0", "steps"),
    (RL + " --target-lighting 1 --stage1-transfer-radius -1", "`--stage1-transfer-radius` is -1"),
    (RL + " --target-lighting 9", "`--target-lighting` is 9"),
    (RL + " --input-lighting 3 --target-lighting 1", "`--input-lighting` is 3"),
    (RL, "Pass `--target-lighting K`"),
    (RL + " --target-lighting 1 --envmap city", "not both"),
    (RL + " --envmap nowhere.exr", "neither a file nor a bundled HDRI"),
    (RL + " --target-lighting 1 --envmaps {missing}", "`--envmaps`"),
    (RL + " --target-lighting 1 --checkpoint {missing}", "`--checkpoint`"),
    (RL + " --target-lighting 1 --base-model {tmp}", "goes with the authors'"),
    (RL + " --target-lighting 1 --diffusion-preset tiny --checkpoint {tmp}", "random smoke"),
    ("relight {missing} --data {data} --out {out} --target-lighting 1", "not a gaffer-nerf ch"),
    ("relight {badfield} --data {data} --out {out} --target-lighting 1", "truncated or not a"),
    ("relight {badcfg} --data {data} --out {out} --target-lighting 1", "is not valid JSON"),
    (RL + " --target-lighting 1 --out {under_file}", "is a file, not a folder"),
    ("render {field} --data {data} --out {out} --orbit 0", "`--orbit` is 0"),
    ("render {field} --data {data} --out {out} --orbit 100000", "1..3600"),
    ("render {field} --data {data} --out {out} --orbit 4 --fps 0", "`--fps` is 0.0"),
    ("render {field} --data {data} --out {out} --orbit 4 --fps nan", "`--fps` is nan"),
    ("render {field} --data {notest} --out {out}", "pick --split train"),
    ("render {field} --data {data} --out {file}", "is a file, not a folder; pass a folder"),
    ("evaluate {field} --data {data} --target-lighting 7", "`--target-lighting` is 7"),
    ("evaluate {field} --data {data} --target-lighting 1 --json {tmp}", "is a folder; pass a"),
    ("evaluate {field} --data {data} --target-lighting 1 --pred-dir {file}", "is a file"),
    ("evaluate {field} --data {data} --target-lighting 1 --json {under_file}", "not a folder"),
    # a file or folder the command writes inside its output folder is of the other kind,
    # or the output is one of the inputs
    ("fit {data} --out {slots}", "field.safetensors is a folder"),
    (RL + " --target-lighting 1 --out {slots}", "field.safetensors is a folder"),
    (RL + " --target-lighting 1 --out {views_file}", "relit_views is a file"),
    (RL + " --target-lighting 1 --out {field}", "is the input `field`"),
    (RL + " --target-lighting 1 --out {data}", "is the input `--data`"),
    (RL + " --target-lighting 1 --out {file}", "is a file, not a folder"),
    ("render {field} --data {data} --out {slots}", "000.png is a folder"),
    ("render {field} --data {data} --out {slots} --orbit 4", "orbit.gif is a folder"),
    ("evaluate {field} --data {data} --target-lighting 1 --pred-dir {slots}", "000.png is a fo"),
]


def test_every_refusal_is_one_line_before_torch_is_imported(paths: dict[str, str]) -> None:
    """One fresh interpreter runs the whole table: torch must still be unimported at the end."""
    argvs = [[*cmd.format(**paths).split(), "--no-progress"] for cmd, _ in CASES]
    script = textwrap.dedent(
        """
        import contextlib, io, json, sys
        from gaffer_nerf.cli import main
        results = []
        for argv in json.loads(sys.argv[1]):
            err = io.StringIO()
            with contextlib.redirect_stderr(err):
                code = main(argv)
            results.append([code, err.getvalue()])
        print(json.dumps({"results": results, "torch": "torch" in sys.modules}))
        """
    )
    run = subprocess.run(
        [sys.executable, "-c", script, json.dumps(argvs)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    got = json.loads(run.stdout.splitlines()[-1])
    failures = []
    for (cmd, words), (code, err) in zip(CASES, got["results"], strict=True):
        lines = [ln for ln in err.splitlines() if ln.strip()]
        if code != 2 or words not in err or len(lines) != 1 or "Traceback" in err:
            failures.append(f"{cmd}: exit {code}, stderr {err!r}")
    assert failures == []
    assert got["torch"] is False, "a refusal imported torch"
    assert not Path(paths["out"]).exists(), "a refusal created the output folder"


def test_importing_the_cli_does_not_import_torch() -> None:
    code = "import sys, gaffer_nerf, gaffer_nerf.cli; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "False", out.stderr


def test_lazy_package_exports_resolve() -> None:
    import gaffer_nerf

    assert set(gaffer_nerf.__all__) <= set(dir(gaffer_nerf))
    for name in gaffer_nerf.__all__:
        assert getattr(gaffer_nerf, name) is not None
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        _ = gaffer_nerf.nope  # type: ignore[attr-defined]


def test_a_device_this_machine_lacks_is_one_line_before_any_loading(
    paths: dict[str, str], capsys: pytest.CaptureFixture[str]
) -> None:
    torch = pytest.importorskip("torch")
    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    argv = ["fit", paths["data"], "--out", paths["out"], "--device", "cuda", "--no-progress"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "`--device` is 'cuda'" in err and "pass cpu" in err and len(err.splitlines()) == 1
    assert not Path(paths["out"]).exists()
