"""Command line: `gaffer-diffusion demo | relight | evaluate | init-random | train`.

    gaffer-diffusion demo --out DIR [--checkpoint CKPT] [--steps N] [--frames 24]
        (README's main job: the shipped example object relit under the bundled HDRIs and a turntable;
        PNGs, a GIF, metrics.json and report.html)
    gaffer-diffusion relight IMAGE --envmap ENV.exr (--w2c W2C.npy | --azimuth DEG --elevation DEG)
        [--checkpoint CKPT] [--base-model DIR] --out OUT.png [--steps N] [--guidance S] [--seed 0]
        [--turntable N]
    gaffer-diffusion relight IMAGE --ldr LDR.png --hdr HDR.png --checkpoint CKPT ... (pre-encoded maps)
    gaffer-diffusion relight IMAGES_DIR --envmaps ENVMAPS_DIR (--w2c | --azimuth --elevation)
        --checkpoint CKPT --out OUT_DIR   (every image x every map, batched; OUT_DIR/<image>/<map>.png)
    gaffer-diffusion insert OBJECT --into BACKGROUND --out OUT.png [--at X,Y] [--height H]
        [--envmap ENV.exr [--w2c W2C.npy] | --light-from-photo --key-light AZ,EL] [--shadow 2d|none]
        (the object relit under the background's lighting, placed, with a cast shadow)
    gaffer-diffusion evaluate --dataset DIR --checkpoint CKPT [--base-model DIR] [--envmaps DIR]
        [--steps 50] [--limit N] [--json F] [--markdown F]   (a gaffer-data rendered dataset)
    gaffer-diffusion evaluate --pred DIR --gt DIR [--mask-dir DIR] [--lpips-backbone FILE] [--json F]
    gaffer-diffusion normals IMAGE --out NORMALS.png [--mask M|auto] [--output-size input|model]
    gaffer-diffusion train-normals --data RENDERS --val RENDERS --out DIR [--minutes 15]
    gaffer-diffusion prepare IMAGE --out OUT.png [--mask M] [--compat neural-gaffer|default]
        (the model-ready square input on white and OUT_mask.png)
    gaffer-diffusion check --checkpoint DIR --base-model DIR   (validate the authors' release first)
    gaffer-diffusion init-random --preset tiny --out DIR   (random weights in our format, for demos)
    gaffer-diffusion train --config CONFIG.json [--resume]   (extra [train]; configs/ has examples)
    gaffer-diffusion app [--host 127.0.0.1] [--port 7860] [--model DIR]   (extra [app]: the browser app)

`--checkpoint` is either our format (a folder with `gaffer_model.json`) or the authors' release
(`checkpoint-80000/`), which also needs `--base-model` (a local Zero-1-to-3 XL diffusers folder).
Without `--checkpoint`, `relight` and `demo` use gaffer-tiny, the 128 px model shipped in the package.

The code: `parser.py` builds the parser; `relight`, `evaluate` and `insert` turn the parsed arguments
into a typed request once (`_from_args.py` builds the `_requests.py` dataclasses, performing every
refusal and reading each input file once) and their modules (`relight.py`, `evaluate.py`,
`insert.py`) run it; the other commands' modules (`demo.py`, `normals.py`, `authors.py` for
prepare/check, `train.py` for train/export/init-random) check and run their own flags. `_common.py`,
`_flag_checks.py`, `_lighting.py` and `_photo.py` hold what they share. `main` (here) dispatches and
turns every error into one line and an exit status.

Exit codes (`parser.EXIT_CODES`): 0 done; 1 `relight` on a folder wrote some images but others
failed (listed); 2 refused or failed (one stderr line naming the argument and the fix); 130
interrupted (Ctrl-C). `--debug` also prints the traceback of an expected failure.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

# Only torch-free modules at import time: every argument is checked before torch, diffusers or a
# model loads, so a refusal takes well under a second; the rest is imported where used. The `_from_args`
# names are one part of a request at a time, re-exported for tests and tools that import them from
# `gaffer_diffusion.cli` (the module this was); not in `__all__`, so the API docs show `main` only.
from gaffer_diffusion.cli._from_args import _check_photo_flags as _check_photo_flags
from gaffer_diffusion.cli._from_args import _compat as _compat
from gaffer_diffusion.cli._from_args import _envmap_lighting as _envmap_lighting
from gaffer_diffusion.cli._from_args import _latent_mode as _latent_mode
from gaffer_diffusion.cli._from_args import _object_fraction as _object_fraction
from gaffer_diffusion.cli._from_args import _runtime as _runtime
from gaffer_diffusion.cli._from_args import _sampling as _sampling
from gaffer_diffusion.cli.authors import _check, _prepare
from gaffer_diffusion.cli.demo import _demo
from gaffer_diffusion.cli.evaluate import _evaluate
from gaffer_diffusion.cli.insert import _insert
from gaffer_diffusion.cli.normals import _normals, _train_normals
from gaffer_diffusion.cli.parser import _parser
from gaffer_diffusion.cli.relight import _relight
from gaffer_diffusion.cli.train import _export, _init_random, _train
from gaffer_envmap.cli_support import cli_failure
from gaffer_envmap.errors import GafferError

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `gaffer-diffusion` console script; returns the exit status."""
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        match args.command:
            case "demo":
                return _demo(args)
            case "relight":
                return _relight(args)
            case "insert":
                return _insert(args)
            case "evaluate":
                return _evaluate(args)
            case "init-random":
                return _init_random(args)
            case "prepare":
                return _prepare(args)
            case "check":
                return _check(args)
            case "normals":
                return _normals(args)
            case "train-normals":
                return _train_normals(args)
            case "train":
                return _train(args)
            case "export":
                return _export(args)
            case "app":
                from gaffer_diffusion.app import run_app  # Gradio loads only here

                return run_app(args)
    except GafferError as exc:  # any gaffer package's error (an unreadable EXR is also an OSError)
        return cli_failure(f"error: {exc.diagnostics()}", 2, args)  # --debug: traceback first
    except KeyboardInterrupt:  # Ctrl-C: one line, not a traceback; outputs are written atomically
        return cli_failure(
            "interrupted (Ctrl-C): stopped; files already written are complete "
            "(train: --resume continues from the last checkpoint)",
            130,
            args,
        )
    except OSError as exc:  # an unwritable or clashing output path, a full disk
        return cli_failure(f"error: {exc}. Check the path's permissions and free space.", 2, args)
    except Exception as exc:  # errors from gaffer-envmap (reading EXRs, poses) carry their own fix
        if type(exc).__module__.startswith("gaffer_envmap"):
            return cli_failure(f"error: {exc}", 2, args)
        raise
    return 1
