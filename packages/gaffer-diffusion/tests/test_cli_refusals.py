"""Bad arguments are refused before torch is imported or a model loaded.

Every case runs in one fresh interpreter, which must end without `torch` or `diffusers` in
`sys.modules`: that is what makes a refusal take a fraction of a second instead of seconds. Each
refusal is one stderr line naming the flag, exit status 2, and nothing written at the output path.
"""

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

_HAS_NVIDIA = any(Path("/dev").glob("nvidia[0-9]*"))


def _files(tmp: Path) -> dict[str, str]:
    rgba = np.zeros((40, 30, 4), np.uint8)
    rgba[8:32, 6:24] = (200, 120, 80, 255)
    Image.fromarray(rgba).save(tmp / "good.png")
    Image.fromarray(np.zeros((1, 1, 4), np.uint8)).save(tmp / "tiny.png")
    (tmp / "garbage.png").write_text("not an image")
    (tmp / "empty.png").write_bytes(b"")
    np.save(tmp / "strings.npy", np.array(["a", "b"]))
    np.save(tmp / "w2c_nan.npy", np.full((3, 4), np.nan))
    (tmp / "afile").write_text("a file where a folder is expected")
    (tmp / "garbage.json").write_text("{not json")
    (tmp / "text.exr").write_text("not an EXR")
    (tmp / "adir").mkdir()
    (tmp / "emptydir").mkdir()
    Image.fromarray(rgba).save(tmp / "q_mask.png")  # a photo named like prepare's second output
    # output folders whose slots hold the wrong kind (a folder where a file goes, or the
    # reverse), and a folder of images for the grid mode
    for slot in ("slot/o.mask.png", "spin/t_000.png", "prep/q_mask.png", "nrm/n.mask.png"):
        (tmp / slot).mkdir(parents=True)
    (tmp / "imgs").mkdir()
    Image.fromarray(rgba).save(tmp / "imgs" / "good.png")
    (tmp / "grid").mkdir()
    (tmp / "grid" / "good").write_text("a file where the image's output folder goes")
    (tmp / "model").mkdir()
    (tmp / "model" / "unet").write_text("a file where a model's unet/ goes")
    return {k: str(tmp / k) for k in ("good.png", "afile", "adir", "emptydir")}


def _cases(tmp: Path) -> list[tuple[list[str], str, str | None]]:
    """(argv, words the error must contain, output path that must not appear)."""
    f = _files(tmp)
    good, afile, adir = f["good.png"], f["afile"], f["adir"]
    out = str(tmp / "o.png")
    light = ["--envmap", "city", "--azimuth", "0", "--elevation", "10"]

    def relight(*extra: str, image: str = good, out: str = out) -> list[str]:
        return ["relight", image, *light, "--out", out, *extra]

    cases: list[tuple[list[str], str, str | None]] = [
        (relight(image=str(tmp / "missing.png")), "`IMAGE`", out),
        (relight(image=str(tmp / "garbage.png")), "not a readable image", out),
        (relight(image=str(tmp / "empty.png")), "empty", out),
        (relight(image=str(tmp / "tiny.png")), "1x1", out),
        (["relight", good, "--envmap", "city", "--azimuth", "0", "--elevation", "999", "--out", out],
         "`--elevation`", out),
        (["relight", good, "--envmap", "city", "--azimuth", "nan", "--elevation", "0", "--out", out],
         "`--azimuth`", out),
        (["relight", good, "--envmap", "nope", "--azimuth", "0", "--elevation", "0", "--out", out],
         "bundled HDRI", out),
        (["relight", good, "--envmap", "city", "--w2c", str(tmp / "strings.npy"), "--out", out],
         "`--w2c`", out),
        (["relight", good, "--envmap", "city", "--w2c", str(tmp / "w2c_nan.npy"), "--out", out],
         "NaN", out),
        (["relight", good, "--envmap", "city", "--out", out], "--azimuth", out),
        (["relight", good, "--envmap", str(tmp / "text.exr"), "--azimuth", "0", "--elevation", "0",
          "--out", out], "not a valid .exr", out),
        (relight("--steps", "0"), "`--steps`", out),
        (relight("--guidance", "inf"), "`--guidance`", out),
        (relight("--batch-size", "0"), "`--batch-size`", out),
        (relight("--turntable", "100000"), "`--turntable`", str(tmp / "o_000.png")),
        (relight("--turntable", "4", "--fps", "0"), "`--fps`", str(tmp / "o_000.png")),
        (relight("--turntable", "-1"), "`--turntable`", out),
        (relight(out=str(Path(afile) / "o.png")), "`--out`", None),
        (relight(out=adir), "`--out`", None),
        (relight("--checkpoint", str(tmp / "no-model")), "`--checkpoint`", out),
        (relight("--checkpoint", adir), "--base-model", out),
        (relight("--mask", str(tmp / "no-mask.png")), "`--mask`", out),
        (relight("--device", "tpu"), "`--device`", out),
        (["evaluate", "--pred", str(tmp / "nope"), "--gt", adir], "`--pred`", None),
        (["evaluate", "--pred", adir, "--gt", adir, "--json", str(Path(afile) / "r.json")],
         "`--json`", None),
        (["evaluate", "--pred", adir, "--gt", adir, "--json", adir], "`--json`", None),
        (["evaluate", "--dataset", f["emptydir"]], "not a gaffer-data dataset", None),
        (["evaluate", "--dataset", adir, "--pred", adir], "not both", None),
        (["demo", "--out", afile], "`--out`", None),
        (["demo", "--out", str(tmp / "d"), "--steps", "0"], "`--steps`", str(tmp / "d")),
        (["demo", "--out", str(tmp / "d"), "--fps", "nan"], "`--fps`", str(tmp / "d")),
        (["demo", "--out", str(tmp / "d"), "--frames", "-3"], "`--frames`", str(tmp / "d")),
        (["demo", "--out", str(tmp / "d"), "--threads", "0"], "`--threads`", str(tmp / "d")),
        (["demo", "--out", str(tmp / "d"), "--turntable-hdri", "nope"], "`--turntable-hdri`",
         str(tmp / "d")),
        (["demo", "--out", str(tmp / "d"), "--checkpoint", adir], "gaffer_model.json",
         str(tmp / "d")),
        (["prepare", good, "--out", out, "--size", "100000"], "`--size`", out),
        (["prepare", str(tmp / "garbage.png"), "--out", out], "not a readable image", out),
        (["init-random", "--out", str(Path(afile) / "m")], "`--out`", None),
        (["train", "--config", str(tmp / "garbage.json")], "not valid JSON", None),
        # bad output paths, before any work
        (relight(out=good), "is the input `IMAGE`", None),
        (relight(out=str(tmp / "slot" / "o.png")), "o.mask.png is a folder", None),
        (relight("--turntable", "2", out=str(tmp / "spin" / "t.png")), "t_000.png is a folder",
         None),
        (["relight", str(tmp / "imgs"), *light, "--out", str(tmp / "grid")],
         "is a file where this command writes a folder", None),
        (["relight", str(tmp / "imgs"), *light, "--out", afile], "`--out`", None),
        (["relight", str(tmp / "imgs"), *light, "--out", str(tmp / "imgs")], "input `IMAGE`",
         None),
        (["prepare", good, "--out", str(tmp / "prep" / "q.png")], "q_mask.png is a folder", None),
        (["prepare", good, "--out", adir], "`--out`", None),
        (["prepare", good, "--out", good], "is the input `IMAGE`", None),
        (["prepare", str(tmp / "q_mask.png"), "--out", str(tmp / "q.png")],
         "q_mask.png is the input `IMAGE`", None),
        (["normals", good, "--out", adir], "`--out`", None),
        (["normals", good, "--out", str(tmp / "nrm" / "n.png")], "n.mask.png is a folder", None),
        (["normals", good, "--out", good], "is the input `IMAGE`", None),
        (["init-random", "--out", afile], "`--out`", None),
        # train-normals replaces its whole --out folder: not the renders, nor a folder of other files
        (["train-normals", "--data", adir, "--out", adir], "is or holds `--data`", None),
        (["train-normals", "--data", adir, "--out", str(tmp)], "is or holds `--data`", None),
        (["train-normals", "--data", adir, "--out", str(tmp / "imgs")],
         "not a normal estimator's", None),
        (["train-normals", "--data", adir, "--out", str(tmp / "nrm-new"), "--steps", "0"],
         "`--steps`", str(tmp / "nrm-new")),
        (["train-normals", "--data", adir, "--data", str(tmp / "nrm-new"), "--out", str(tmp / "n2")],
         "`--data`", str(tmp / "n2")),
        (["train-normals", "--data", adir, "--out", str(tmp / "n2"), "--init", str(tmp / "none")],
         "`--init`", str(tmp / "n2")),
        (["train-normals", "--data", adir, "--out", str(tmp / "n2"), "--lr", "0"],
         "`--lr`", str(tmp / "n2")),
        (["train-normals", "--data", adir, "--out", str(tmp / "n2"), "--widths", "16,30"],
         "multiples of 8", str(tmp / "n2")),
        (["train-normals", "--data", adir, "--out", str(tmp / "n2"), "--widths", "16,x"],
         "`--widths`", str(tmp / "n2")),
        (["train-normals", "--data", adir, "--out", str(tmp / "n2"), "--widths", "16"],
         "`--widths`", str(tmp / "n2")),
        (["train-normals", "--data", adir, "--out", str(tmp / "n2"), "--widths", "16,32",
          "--init", adir], "pass one of them", str(tmp / "n2")),
        (relight(out=str(tmp / "o.jpg")), "pass a .png file", str(tmp / "o.jpg")),
        (["prepare", good, "--out", str(tmp / "q.webp")], "pass a .png file", str(tmp / "q.webp")),
        (["evaluate", "--pred", adir, "--gt", adir, "--json", str(tmp / "r.txt"), "--markdown",
          str(tmp / "r.txt")], "one report would replace the other", str(tmp / "r.txt")),
        (["init-random", "--out", str(tmp / "model")], "unet is a file", None),
        (["train", "--config", str(tmp / "none.json")], "`--config`", None),
        (["export", str(tmp / "no-ckpt"), "--out", str(tmp / "x")], "checkpoint", str(tmp / "x")),
    ]  # fmt: skip
    if not _HAS_NVIDIA:
        cases.append((relight("--device", "cuda"), "`--device cuda`", out))
    return cases


_RUNNER = textwrap.dedent(
    """
    import contextlib, io, json, sys, time
    from gaffer_diffusion.cli import main
    results = []
    for argv in json.loads(sys.argv[1]):
        err = io.StringIO()
        t = time.perf_counter()
        with contextlib.redirect_stderr(err):
            rc = main(argv)
        results.append({"rc": rc, "err": err.getvalue(), "s": time.perf_counter() - t})
    heavy = sorted(m for m in ("torch", "diffusers", "transformers") if m in sys.modules)
    print(json.dumps({"results": results, "heavy": heavy}))
    """
)


def test_refusals_come_before_torch_one_line_each(tmp_path) -> None:
    cases = _cases(tmp_path)
    proc = subprocess.run(
        [sys.executable, "-c", _RUNNER, json.dumps([argv for argv, _, _ in cases])],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    problems = []
    for (argv, words, out), r in zip(cases, report["results"], strict=True):
        lines = [x for x in r["err"].splitlines() if x.strip()]
        if r["rc"] != 2 or len(lines) != 1 or words not in r["err"] or "Traceback" in r["err"]:
            problems.append(f"{argv}: rc {r['rc']}, stderr {r['err']!r} (wanted {words!r})")
        if out is not None and Path(out).exists():
            problems.append(f"{argv}: left {out}")
    assert not problems, "\n".join(problems)
    # the point of checking first: none of these imported torch (3-20 s on a busy 2-core machine)
    assert report["heavy"] == [], report["heavy"]
    assert max(r["s"] for r in report["results"]) < 5.0


@pytest.mark.parametrize("flag", ["--json", "--markdown"])
def test_evaluate_output_checked_before_any_scoring(tmp_path, flag, capsys) -> None:
    from gaffer_diffusion.cli import main

    (tmp_path / "p").mkdir()
    dest = tmp_path / "p" / "sub" / "r.txt"
    (tmp_path / "p" / "sub").write_text("a file")
    assert main(["evaluate", "--pred", str(tmp_path), "--gt", str(tmp_path), flag, str(dest)]) == 2
    err = capsys.readouterr().err
    assert flag in err and len(err.strip().splitlines()) == 1


def test_train_refuses_an_output_dir_that_is_a_file_before_any_data_loads(tmp_path, capsys):
    pytest.importorskip("accelerate")
    from gaffer_diffusion.cli import main

    (tmp_path / "afile").write_text("a file where the run folder goes")
    (tmp_path / "renders").mkdir()
    config = {"output_dir": "afile", "data": {"root": "renders"}}
    (tmp_path / "c.json").write_text(json.dumps(config))
    assert main(["train", "--config", str(tmp_path / "c.json")]) == 2
    err = capsys.readouterr().err
    assert "`--config`" in err and "`output_dir`" in err and "is a file" in err
    assert len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "c.json", "renders"]


def test_the_cli_names_the_estimator_folder_mark_as_the_estimator_does() -> None:
    from gaffer_diffusion.cli.normals import ESTIMATOR_MARK
    from gaffer_diffusion.geometry.estimator import ESTIMATOR_CONFIG_NAME

    assert ESTIMATOR_MARK == ESTIMATOR_CONFIG_NAME
