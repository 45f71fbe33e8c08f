"""Task runner for the gaffer monorepo: the only entry point for tests, lint, benchmarks, docs and demos.

Every install goes through a package's own pyproject.toml and `-c constraints.txt` (numpy<2 for bpy,
the local torch==2.13.0 CPU wheel). Run `python3 -m nox -l` to list sessions.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import nox

nox.needs_version = ">=2024.3.2"
nox.options.default_venv_backend = "virtualenv"
nox.options.sessions = ["lint", "typecheck", "tests", "smoke_train", "docs", "wheels"]
nox.options.reuse_existing_virtualenvs = False

ROOT = Path(__file__).parent
CONSTRAINTS = ("-c", str(ROOT / "constraints.txt"))
PACKAGES = ("gaffer-envmap", "gaffer-data", "gaffer-diffusion", "gaffer-nerf")
# What each package needs beside itself for its test suite (extras + the test dependency group).
# Each package's `all` extra holds everything its own tests need beyond the core dependencies.
TEST_SPECS = tuple(arg for pkg in PACKAGES for arg in ("-e", f"packages/{pkg}[all]"))
TYPECHECKED = ("gaffer-envmap", "gaffer-data", "gaffer-diffusion", "gaffer-nerf")
"""Packages pyright checks in the `typecheck` session: all four (issue 14 item 5)."""
INTEGRATIONS_EDITABLE = ("-e", "integrations/comfyui")
"""The ComfyUI node pack (issue 37): its tests load it from its folder as ComfyUI does (no install,
collected through the root `testpaths`); `lint` installs it so import-linter can read it."""
TEST_TOOLS = ("pytest==9.2.0", "jaxtyping>=0.2.36", "beartype>=0.19", "scipy>=1.11", "bpy==5.0.1")


def _install(session: nox.Session, *args: str) -> None:
    session.install(*CONSTRAINTS, *args)


@nox.session
def tests(session: nox.Session) -> None:
    """All packages' CPU tests plus cross-package tests (bpy renders included, GPU/weights excluded)."""
    _install(session, "torch==2.13.0", "numpy==1.26.4")
    _install(session, *TEST_SPECS, *TEST_TOOLS)
    _install_browser(session)
    session.run("pytest", *session.posargs, env={"PYTHONHASHSEED": "0"})


BROWSER_PACKAGES = ("chromium", "chromium-driver")
"""Debian packages of the app's real-browser test (gaffer-diffusion tests/app/test_app_browser.py)."""


def _install_browser(session: nox.Session) -> None:
    """Install Chromium and its driver through apt-get when missing, as root on Debian (CI); else the
    browser test skips and says why. Quiet: apt's output is shown only when it fails."""
    if shutil.which("chromium") and shutil.which("chromedriver"):
        return
    if not hasattr(os, "geteuid") or os.geteuid() != 0 or shutil.which("apt-get") is None:
        session.log("Chromium missing and no root apt-get here: the app's browser test will skip")
        return
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    for cmd in (
        ["apt-get", "update", "-qq"],
        ["apt-get", "install", "-y", "-qq", *BROWSER_PACKAGES],
    ):
        done = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            session.warn(f"{' '.join(cmd)} failed ({done.returncode}); the browser test will skip:")
            session.warn((done.stdout + done.stderr)[-2000:])
            return
    session.log(f"installed {', '.join(BROWSER_PACKAGES)} for the app's browser test")


@nox.session
def lint(session: nox.Session) -> None:
    """ruff check + format check over the whole tree; import-linter enforces the one-way imports."""
    session.install("ruff==0.17.6", "import-linter>=2.1")
    session.run("ruff", "check", ".")
    session.run("ruff", "format", "--check", ".")
    # Sources only (no dependencies): import-linter reads the code, it does not run it. The ComfyUI
    # node pack (integrations/comfyui, issue 37) has contracts of its own.
    session.install(
        "--no-deps",
        *(arg for pkg in PACKAGES for arg in ("-e", f"packages/{pkg}")),
        *INTEGRATIONS_EDITABLE,
    )
    session.run("lint-imports")


@nox.session
def typecheck(session: nox.Session) -> None:
    """pyright over the packages in `TYPECHECKED` (all four, 0 errors: issue 14 item 5)."""
    _install(session, "torch==2.13.0", "numpy==1.26.4")
    # bpy is left out on purpose (hundreds of MB): its modules declare it has no stubs anyway.
    _install(
        session,
        "-e",
        "packages/gaffer-envmap[hdr,sky]",
        "-e",
        "packages/gaffer-data[filter]",
        "-e",
        "packages/gaffer-diffusion[all]",
        "-e",
        "packages/gaffer-nerf[all]",
        "OpenEXR>=3.3",
        "pillow>=10",
        "pyright==1.1.408",
    )
    python = str(Path(session.virtualenv.location) / "bin" / "python")
    session.run("pyright", "--pythonpath", python, *(f"packages/{p}/src" for p in TYPECHECKED))


@nox.session
def wheels(session: nox.Session) -> None:
    """Build each package's wheel; install and import it alone in a clean venv with only its declared deps."""
    session.install("build>=1.2", "virtualenv>=20")
    dist = Path(tempfile.mkdtemp(prefix="gaffer-dist-"))
    for pkg in PACKAGES:
        session.run("python", "-m", "build", "--wheel", "--outdir", str(dist), f"packages/{pkg}")
    for pkg in PACKAGES:
        module = pkg.replace("-", "_")
        venv_dir = Path(tempfile.mkdtemp(prefix=f"venv-{pkg}-"))
        session.run("python", "-m", "virtualenv", "-q", str(venv_dir))
        py = str(venv_dir / "bin" / "python")
        # torch first, pinned, so the resolver never reaches for a CUDA build (environment.md).
        session.run(py, "-m", "pip", "install", "-q", *CONSTRAINTS, "torch==2.13.0", external=True)
        session.run(
            py,
            "-m",
            "pip",
            "install",
            "-q",
            *CONSTRAINTS,
            "--find-links",
            str(dist),
            pkg,
            external=True,
        )
        session.run(
            py,
            "-c",
            f"import {module}; print({module}.__name__, {module}.__version__)",
            external=True,
        )
        shutil.rmtree(venv_dir, ignore_errors=True)


@nox.session
def demo(session: nox.Session) -> None:
    """README's main job, offline: gaffer-tiny relights the shipped example object under the bundled
    CC0 HDRIs and a turntable (PNGs, a GIF, metrics.json, report.html); then gaffer-envmap's lighting
    demo (a bundled HDRI rotated into camera frames and encoded) into OUT/envmap."""
    _install(session, "torch==2.13.0", "numpy==1.26.4")
    _install(
        session,
        "-e",
        "packages/gaffer-envmap",
        "-e",
        "packages/gaffer-data",
        "-e",
        "packages/gaffer-diffusion[eval]",
    )
    out = Path(session.posargs[0] if session.posargs else "out/demo")
    session.run("gaffer-diffusion", "demo", "--out", str(out))
    session.run("gaffer-envmap", "demo", "--out", str(out / "envmap"))


@nox.session
def smoke_train(session: nox.Session) -> None:
    """Issue 5's CI-scale training run on CPU, from nothing: render a tiny dataset with gaffer-data's
    embedded recipe, train the random-init gaffer-tiny architecture for a few minutes, score held-out
    objects against ground-truth renders beside the unrelit input (`OUT/smoke_report.json`).

    Fails when the loss does not fall or a score is not finite; whether the relit views beat the
    identity baseline at this scale is reported, not required (see the diffusion README's numbers).
    `nox -s smoke_train -- OUT [MINUTES]`.
    """
    _install(session, "torch==2.13.0", "numpy==1.26.4")
    _install(
        session,
        "-e",
        "packages/gaffer-envmap",
        "-e",
        "packages/gaffer-data[render,filter]",
        "-e",
        "packages/gaffer-diffusion[train,metrics]",
    )
    out = Path(session.posargs[0] if session.posargs else "out/smoke_train").resolve()
    minutes = session.posargs[1] if len(session.posargs) > 1 else "3"
    shutil.rmtree(out, ignore_errors=True)  # a fresh run: the smoke script would resume otherwise
    # benchmarks/smoke_train.py: research scaffolding kept out of the gaffer-diffusion wheel
    script = str(ROOT / "benchmarks" / "smoke_train.py")
    session.run("python", script, "--out", str(out), "--minutes", minutes)
    report = json.loads((out / "smoke_report.json").read_text())
    train, held = report["training"], report["heldout_psnr_db"]
    relit = {k: v["psnr_relit"] for k, v in held.items() if k.startswith("steps_")}
    if train["loss_first_10pct"] is None:
        session.error(
            f"smoke training logged no loss in {train['steps']} steps ({train['seconds']:.0f} s): "
            "each step took longer than the run's logging interval allows"
        )
    session.log(
        f"loss {train['loss_first_10pct']:.4f} -> {train['loss_last_10pct']:.4f} in "
        f"{train['steps']} steps; held-out PSNR relit {relit} vs unrelit input "
        f"{held['identity_baseline']:.2f} dB; beats identity: {report['beats_identity']}"
    )
    if not train["loss_falls"]:
        session.error("smoke training: the loss did not fall")
    if not all(math.isfinite(v) for v in [*relit.values(), held["identity_baseline"]]):
        session.error(f"smoke training: a non-finite held-out score {relit}")


@nox.session
def bench(session: nox.Session) -> None:
    """Benchmarks: JSON + PNG plots under benchmarks/results/."""
    _install(session, "torch==2.13.0", "numpy==1.26.4")
    _install(session, *TEST_SPECS, "matplotlib==3.11.2")
    env = {"PYTHONHASHSEED": "0"}
    for script in sorted((ROOT / "benchmarks").glob("bench_*.py")):
        session.run("python", str(script), *session.posargs, env=env)


@nox.session
def docs(session: nox.Session) -> None:
    """Sphinx site with warnings as errors: guides, tutorials, the four packages' API, benchmark charts.

    Every figure, table and API page is generated from code at build time (docs/_scripts/), and every
    `gaffer-*` command shown in the pages is checked against the real CLI parsers. `bpy` is not
    installed (autodoc reads gaffer_data.render with a stand-in); torch goes first, pinned, so that no
    resolver reaches for a CUDA build.
    """
    _install(session, "torch==2.13.0", "numpy==1.26.4")
    _install(
        session,
        "-e",
        "packages/gaffer-envmap[hdr]",
        "-e",
        "packages/gaffer-data",
        "-e",
        "packages/gaffer-diffusion[metrics,train]",
        "-e",
        "packages/gaffer-nerf[all]",
        "matplotlib==3.11.2",
        "sphinx>=8",
        "furo>=2024.8.6",
        "myst-parser>=4",
    )
    session.run(
        "sphinx-build", "-n", "-T", "-W", "--keep-going", "-b", "html", "docs", "docs/_build/html"
    )


if __name__ == "__main__":
    sys.exit("run with: python3 -m nox")
