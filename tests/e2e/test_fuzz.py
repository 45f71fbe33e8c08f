"""Table-driven bad-input suite for the four command lines.

Every row is one invocation of a subcommand of `gaffer-envmap`, `gaffer-data`, `gaffer-diffusion` or
`gaffer-nerf` with a bad or edge-case input: missing, empty, truncated or garbage files, NaN, zero,
negative and absurd counts and sizes, unwritable or clashing outputs. A "refuse" row must end with
a non-zero exit status, exactly one error line on stderr, no traceback, and nothing written: its
working folder (every output path is relative to it) stays empty. A "handle" row is a valid edge
case that must succeed (exit 0, no traceback).

Speed: each CLI runs its rows in one fresh interpreter (a subprocess per CLI, the four in parallel),
calling the console script's own `main(argv)` in a fresh empty working folder per row, with stderr
captured per row and logging re-bound to it. The interpreter's address space is capped
(`RLIMIT_AS`), so an absurd size that is not refused fails with MemoryError instead of taking the
machine down. The whole table takes well under a minute on 2 cores. The summary (tries, clean
refusals, handled edge cases, and each kind of failure) is printed at the end of the run.

A row that fails in a package is marked xfail with the reason (not strict: it passes once fixed).
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import subprocess
import sys
import textwrap
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

MODULES = {
    "gaffer-envmap": "gaffer_envmap.cli",
    "gaffer-data": "gaffer_data.cli",
    "gaffer-diffusion": "gaffer_diffusion.cli",
    "gaffer-nerf": "gaffer_nerf.cli",
}
MEMORY_CAP = 12 * 2**30
"""Address-space cap of each runner: torch needs a few GiB of it; an unrefused absurd size does not fit."""


@dataclass(frozen=True)
class Case:
    """One row: `argv` may hold `{F}` (the folder of bad files, absolute paths)."""

    cli: str
    id: str
    argv: tuple[str, ...]
    expect: str = "refuse"  # or "handle"
    words: str = ""  # the error line must contain this (refusals), when given
    xfail: str = ""  # reason, for a row that fails in a package today
    marks: tuple = field(default_factory=tuple)


def _c(cli: str, id: str, argv: str, **kw) -> Case:
    return Case(cli=cli, id=f"{cli.removeprefix('gaffer-')}:{id}", argv=tuple(argv.split()), **kw)


E, D, G, N = "gaffer-envmap", "gaffer-data", "gaffer-diffusion", "gaffer-nerf"
CITY = "{F}/city.exr"
LONG = "x" * 300  # a file name longer than file systems allow (255 bytes)
LIGHT = "--envmap city --azimuth 0 --elevation 10"
INS = "{F}/good.png --into {F}/photo.jpg"

CASES: list[Case] = [
    # --- gaffer-envmap ------------------------------------------------------------------------
    _c(E, "info-missing", "info {F}/missing.exr"),
    _c(E, "info-empty", "info {F}/empty.exr"),
    _c(E, "info-text-exr", "info {F}/text.exr"),
    _c(E, "info-text-hdr", "info {F}/text.hdr"),
    _c(E, "info-truncated", "info {F}/truncated.exr"),
    _c(E, "info-folder", "info {F}/emptydir"),
    _c(E, "info-bundled", f"info {CITY}", expect="handle"),
    _c(E, "rotate-spin-nan", f"rotate {CITY} dst.exr --w2c {{F}}/w2c.npy --spin nan"),
    _c(E, "rotate-w2c-strings", f"rotate {CITY} dst.exr --w2c {{F}}/w2c_strings.npy"),
    _c(E, "rotate-w2c-pickle", f"rotate {CITY} dst.exr --w2c {{F}}/w2c_pickle.npy"),
    _c(E, "rotate-w2c-empty", f"rotate {CITY} dst.exr --w2c {{F}}/w2c_empty.npy"),
    _c(E, "rotate-w2c-text", f"rotate {CITY} dst.exr --w2c {{F}}/w2c_text.npy"),
    _c(E, "rotate-w2c-nan", f"rotate {CITY} dst.exr --w2c {{F}}/w2c_nan.npy"),
    _c(E, "rotate-size-0", f"rotate {CITY} dst.exr --w2c {{F}}/w2c.npy --size 0"),
    _c(E, "rotate-size-absurd", f"rotate {CITY} dst.exr --w2c {{F}}/w2c.npy --size 100000"),
    _c(E, "rotate-nan-map", "rotate {F}/nan.exr dst.exr --w2c {F}/w2c.npy --sanitize raise"),
    _c(E, "rotate-into-file", f"rotate {CITY} {{F}}/afile/dst.exr --w2c {{F}}/w2c.npy"),
    _c(E, "encode-into-file", f"encode {CITY} --w2c {{F}}/w2c.npy --out-dir {{F}}/afile/enc"),
    _c(E, "encode-size-0", f"encode {CITY} --w2c {{F}}/w2c.npy --out-dir enc --size 0"),
    _c(E, "augment-yaw-0", f"augment {CITY} --out-dir aug --yaw-steps 0"),
    _c(E, "augment-yaw-negative", f"augment {CITY} --out-dir aug --yaw-steps -3"),
    _c(E, "augment-missing", "augment {F}/missing.exr --out-dir aug"),
    _c(E, "procedural-count-0", "procedural --out-dir proc --count 0"),
    _c(E, "procedural-count-negative", "procedural --out-dir proc --count -1"),
    _c(E, "procedural-height-0", "procedural --out-dir proc --height 0"),
    _c(E, "procedural-into-file", "procedural --out-dir {F}/afile --count 1"),
    # a file where a folder is expected and the reverse, inside an output folder too, a
    # format without its writer or suffix, an output that is an input: refused before any work
    _c(E, "rotate-dst-folder", f"rotate {CITY} {{F}}/emptydir --w2c {{F}}/w2c.npy", words="`dst`"),
    _c(E, "rotate-dst-no-suffix", f"rotate {CITY} dst --w2c {{F}}/w2c.npy", words="`dst`"),
    _c(E, "rotate-dst-png", f"rotate {CITY} dst.png --w2c {{F}}/w2c.npy", words="`dst`"),
    _c(E, "rotate-dst-is-src", f"rotate {CITY} {CITY} --w2c {{F}}/w2c.npy", words="`src`"),
    _c(E, "encode-out-dir-file", f"encode {CITY} --w2c {{F}}/w2c.npy --out-dir {{F}}/afile",
       words="`--out-dir`"),
    _c(E, "encode-slot-folder", f"encode {CITY} --w2c {{F}}/w2c.npy --out-dir {{F}}/slots",
       words="ldr.png is a folder"),
    _c(E, "augment-out-dir-file", f"augment {CITY} --out-dir {{F}}/afile", words="`--out-dir`"),
    _c(E, "procedural-slot-folder", "procedural --out-dir {F}/slots --count 1 --height 8",
       words="proc_0000.exr is a folder"),
    _c(E, "demo-out-file", "demo --out {F}/afile --size 16", words="`--out`"),
    _c(E, "demo-slot-folder", "demo --out {F}/slots --size 16", words="overview.png is a folder"),
    _c(E, "demo-out-empty", "demo --out '' --size 16", words="argument --out: is empty"),
    _c(E, "rotate-dst-name-too-long", f"rotate {CITY} {LONG}.exr --w2c {{F}}/w2c.npy",
       words="`dst`"),
    _c(E, "encode-out-dir-is-src", "encode {F}/ldrmap/ldr.png --w2c {F}/w2c.npy --out-dir {F}/ldrmap",
       words="`src`"),
    # sky: bad angles, a time without offset, an unknown model or word, a folder
    _c(E, "sky-sun-elevation-120", "sky --sun-elevation 120 --sun-azimuth 0 --out s.exr",
       words="--sun-elevation"),
    _c(E, "sky-time-no-offset", "sky --at 48.86,2.29 --time 2026-06-21T12:00 --out s.exr",
       words="`--time`"),
    _c(E, "sky-model-unknown", "sky --text noon --model foo --out s.exr", words="--model"),
    _c(E, "sky-strict-unknown-word", "sky --text noon,fluffy --strict --out s.exr",
       words="'fluffy'"),
    _c(E, "sky-out-folder", "sky --text noon --out {F}/emptydir", words="`--out`"),
    # lighting sources: plugins of the entry-point group gaffer.envmap_sources
    _c(E, "sky-source-unknown", "sky --source nope --text noon --out s.exr",
       words="installed: sky"),
    _c(E, "sky-source-no-text", "sky --source sky --out s.exr", words="`--text PHRASE`"),
    _c(E, "sky-source-option-alone", "sky --text noon --source-option a=b --out s.exr",
       words="`--source-option`"),
    _c(E, "sky-source-option-unknown", "sky --source sky --text noon --source-option foo=1 --out s.exr",
       words="takes exposure, strict"),
    _c(E, "sky-source-with-model", "sky --source sky --text noon --model preetham --out s.exr",
       words="`--model`"),
    _c(E, "sky-source-strict-word",
       "sky --source sky --text noon,fluffy --source-option strict=1 --out s.exr", words="'fluffy'"),
    _c(E, "sky-source-sky", "sky --source sky --text noon --width 16 --out s.exr", expect="handle"),
    _c(E, "sources-list", "sources", expect="handle"),
    # --- gaffer-data --------------------------------------------------------------------------
    _c(D, "recipe-empty-out", "recipe ''"),
    _c(D, "recipe-procedural-negative", "recipe rec --procedural -1"),
    _c(D, "recipe-procedural-absurd", "recipe rec --procedural 100000"),
    _c(D, "recipe-into-file", "recipe {F}/afile/rec"),
    _c(D, "info-missing", "info {F}/missing"),
    _c(D, "info-empty-folder", "info {F}/emptydir"),
    _c(D, "info-unrelated-folder", "info {F}/unrelated"),
    _c(D, "info-file", "info {F}/afile"),
    _c(D, "render-missing", "render --objects {F}/missing --envmaps {F}/missing --out ren"),
    _c(D, "render-empty", "render --objects {F}/emptydir --envmaps {F}/emptydir --out ren"),
    _c(D, "render-timeout-negative",
       "render --objects {F}/emptydir --envmaps {F}/maps --out ren --timeout -5"),
    _c(D, "render-resolution-absurd",
       "render --objects {F}/emptydir --envmaps {F}/maps --out ren --resolution 100000"),
    _c(D, "render-wide-map", "render --objects {F}/emptydir --envmaps {F}/wide --out ren"),
    _c(D, "train-classifier-garbage",
       "train-classifier {F}/garbage.json {F}/garbage.json --out clf.json"),
    _c(D, "schema-into-file", "schema --out {F}/afile/schema"),
    _c(D, "schema", "schema --out schema", expect="handle"),
    _c(D, "recipe-out-file", "recipe {F}/afile --procedural 0", words="`out`"),
    _c(D, "recipe-slot-file", "recipe {F}/slots --procedural 0", words="objects is a file"),
    _c(D, "recipe-seed-negative", "recipe rec --procedural 1 --seed -1", words="`--seed`"),
    _c(D, "render-out-file", "render --objects {F}/emptydir --envmaps {F}/maps --out {F}/afile",
       words="`--out`"),
    _c(D, "render-slot-folder", "render --objects {F}/emptydir --envmaps {F}/maps --out {F}/slots",
       words="dataset.json is a folder"),
    _c(D, "render-seed-negative",
       "render --objects {F}/emptydir --envmaps {F}/maps --out ren --seed -1", words="`--seed`"),
    _c(D, "render-multiview-out-file",
       "render-multiview --objects {F}/emptydir --envmaps {F}/maps --out {F}/afile", words="`--out`"),
    _c(D, "schema-out-file", "schema --out {F}/afile", words="`--out`"),
    _c(D, "schema-out-empty", "schema --out ''", words="argument --out: is empty"),
    _c(D, "render-out-empty", "render --objects {F}/emptydir --envmaps {F}/maps --out ''",
       words="argument --out: is empty"),
    _c(D, "schema-out-name-too-long", f"schema --out new/{LONG}", words="`--out`"),
    _c(D, "filter-out-folder", "filter {F}/emptydir --out {F}/emptydir", words="`--out`"),
    _c(D, "train-classifier-out-file",
       "train-classifier {F}/garbage.json {F}/garbage.json --out {F}/afile", words="`--out`"),
    _c(D, "convert-authors-out-file", "convert-authors {F}/emptydir --out {F}/afile",
       words="`--out`"),
    # --- gaffer-diffusion ---------------------------------------------------------------------
    _c(G, "relight-missing", f"relight {{F}}/missing.png {LIGHT} --out o.png", words="IMAGE"),
    _c(G, "relight-garbage", f"relight {{F}}/garbage.png {LIGHT} --out o.png"),
    _c(G, "relight-empty", f"relight {{F}}/empty.png {LIGHT} --out o.png"),
    _c(G, "relight-1x1", f"relight {{F}}/tiny.png {LIGHT} --out o.png", words="1x1"),
    _c(G, "relight-elevation-999",
       "relight {F}/good.png --envmap city --azimuth 0 --elevation 999 --out o.png"),
    _c(G, "relight-azimuth-nan",
       "relight {F}/good.png --envmap city --azimuth nan --elevation 0 --out o.png"),
    _c(G, "relight-text-envmap",
       "relight {F}/good.png --envmap {F}/text.exr --azimuth 0 --elevation 0 --out o.png"),
    _c(G, "relight-w2c-pickle",
       "relight {F}/good.png --envmap city --w2c {F}/w2c_pickle.npy --out o.png"),
    _c(G, "relight-w2c-empty",
       "relight {F}/good.png --envmap city --w2c {F}/w2c_empty.npy --out o.png"),
    _c(G, "relight-steps-0", f"relight {{F}}/good.png {LIGHT} --out o.png --steps 0"),
    _c(G, "relight-turntable-absurd",
       f"relight {{F}}/good.png {LIGHT} --out o.png --turntable 100000"),
    _c(G, "relight-fps-0", f"relight {{F}}/good.png {LIGHT} --out o.png --turntable 4 --fps 0"),
    _c(G, "relight-into-file", f"relight {{F}}/good.png {LIGHT} --out {{F}}/afile/o.png"),
    _c(G, "relight-checkpoint-missing",
       f"relight {{F}}/good.png {LIGHT} --out o.png --checkpoint {{F}}/missing"),
    _c(G, "relight-device-bogus", f"relight {{F}}/good.png {LIGHT} --out o.png --device tpu"),
    _c(G, "evaluate-json-into-file",
       "evaluate --pred {F}/emptydir --gt {F}/emptydir --json {F}/afile/r.json"),
    _c(G, "evaluate-empty-dataset", "evaluate --dataset {F}/emptydir"),
    _c(G, "demo-into-file", "demo --out {F}/afile"),
    _c(G, "demo-frames-negative", "demo --out d --frames -1"),
    _c(G, "demo-fps-nan", "demo --out d --fps nan"),
    _c(G, "prepare-size-absurd", "prepare {F}/good.png --out p.png --size 100000"),
    _c(G, "train-config-garbage", "train --config {F}/garbage.json"),
    _c(G, "prepare-gray16", "prepare {F}/gray16.png --mask {F}/mask.png --out p.png --size 32",
       expect="handle"),
    _c(G, "relight-out-folder", f"relight {{F}}/good.png {LIGHT} --out {{F}}/emptydir",
       words="`--out`"),
    _c(G, "relight-out-is-image", f"relight {{F}}/good.png {LIGHT} --out {{F}}/good.png",
       words="`IMAGE`"),
    _c(G, "relight-mask-slot-folder", f"relight {{F}}/good.png {LIGHT} --out {{F}}/slots/o.png",
       words="o.mask.png is a folder"),
    _c(G, "relight-frame-slot-folder",
       f"relight {{F}}/good.png {LIGHT} --out {{F}}/slots/t.png --turntable 2",
       words="t_000.png is a folder"),
    _c(G, "prepare-out-folder", "prepare {F}/good.png --out {F}/emptydir", words="`--out`"),
    _c(G, "relight-out-name-too-long", f"relight {{F}}/good.png {LIGHT} --out {LONG}.png",
       words="`--out`"),
    _c(G, "relight-out-fifo", f"relight {{F}}/good.png {LIGHT} --out {{F}}/fifo.png",
       words="not a regular file"),
    _c(G, "relight-out-jpg", f"relight {{F}}/good.png {LIGHT} --out o.jpg", words="`--out`"),
    _c(G, "evaluate-json-is-markdown",
       "evaluate --pred {F}/emptydir --gt {F}/emptydir --json r.txt --markdown r.txt",
       words="`--markdown`"),
    _c(G, "prepare-mask-slot-folder", "prepare {F}/good.png --out {F}/slots/q.png",
       words="q_mask.png is a folder"),
    _c(G, "normals-out-folder", "normals {F}/good.png --out {F}/emptydir", words="`--out`"),
    _c(G, "init-random-out-file", "init-random --out {F}/afile", words="`--out`"),
    _c(G, "init-random-slot-file", "init-random --out {F}/slots", words="unet is a file"),
    _c(G, "train-output-dir-file", "train --config {F}/train_into_file.json", words="output_dir"),
    _c(G, "train-normals-out-is-data", "train-normals --data {F}/maps --out {F}/maps",
       words="`--data`"),
    _c(G, "train-normals-out-not-estimator", "train-normals --data {F}/maps --out {F}/unrelated",
       words="`--out`"),
    _c(G, "train-normals-init-missing",
       "train-normals --data {F}/maps --out {F}/nrm --init {F}/missing", words="`--init`"),
    _c(G, "train-normals-init-file", "train-normals --data {F}/maps --out {F}/nrm --init {F}/afile",
       words="`--init`"),
    _c(G, "train-normals-second-data-missing",
       "train-normals --data {F}/maps --data {F}/missing --out {F}/nrm", words="`--data`"),
    _c(G, "train-normals-lr-zero", "train-normals --data {F}/maps --out {F}/nrm --lr 0",
       words="`--lr`"),
    _c(G, "train-normals-lr-nan", "train-normals --data {F}/maps --out {F}/nrm --lr nan",
       words="`--lr`"),
    # a photo without a usable alpha: its mask is estimated (the app's GrabCut), not refused
    _c(G, "prepare-rgb-photo", "prepare {F}/photo.jpg --out p.png --size 32", expect="handle"),
    _c(G, "prepare-opaque-rgba", "prepare {F}/opaque.png --out p.png --size 32", expect="handle"),
    # insert: the object good.png (30x40) into the background photo.jpg (80x60)
    _c(G, "insert-mask-size", f"insert {INS} --mask {{F}}/photo.jpg --out o.png", words="`--mask`"),
    _c(G, "insert-at-outside", f"insert {INS} --at 80,10 --out o.png", words="`--at`"),
    _c(G, "insert-height-too-tall", f"insert {INS} --at 40,50 --height 60 --out o.png",
       words="`--height` 51 or less"),
    _c(G, "insert-height-0", f"insert {INS} --height 0 --out o.png", words="`--height`"),
    _c(G, "insert-text-envmap", f"insert {INS} --envmap {{F}}/text.exr --out o.png",
       words="`--envmap`"),
    _c(G, "insert-truncated-envmap", f"insert {INS} --envmap {{F}}/truncated.exr --out o.png"),
    _c(G, "insert-key-light-nan", f"insert {INS} --key-light nan,30 --out o.png",
       words="`--key-light`"),
    _c(G, "insert-key-light-with-envmap", f"insert {INS} --envmap city --key-light 90,30 --out o.png",
       words="`--key-light`"),
    _c(G, "insert-save-envmap-png", f"insert {INS} --save-envmap e.png --out o.png",
       words="`--save-envmap`"),
    _c(G, "insert-out-is-background", "insert {F}/good.png --into {F}/opaque.png --out {F}/opaque.png",
       words="`--into`"),
    _c(G, "insert-sun-at-no-heading",
       f"insert {INS} --sun-at 48.86,2.29,2026-06-21T17:00+02:00 --out o.png",
       words="`--camera-heading"),
    _c(G, "insert-sun-at-night",
       f"insert {INS} --sun-at 48.86,2.29,2026-06-21T23:30+02:00 --camera-heading 0 --out o.png"),
    _c(G, "insert-default", f"insert {INS} --out o.png --save-envmap e.exr", expect="handle"),
    _c(G, "insert-light-source-unknown", f"insert {INS} --light-source nope --out o.png",
       words="`--light-source` 'nope'"),
    _c(G, "insert-light-text-alone", f"insert {INS} --light-text noon --out o.png",
       words="`--light-text`"),
    _c(G, "insert-light-source-with-envmap",
       f"insert {INS} --light-source sky --light-text noon --envmap city --out o.png",
       words="drop `--envmap`"),
    _c(G, "insert-light-source-no-text", f"insert {INS} --light-source sky --out o.png",
       words="`--light-text PHRASE`"),
    _c(G, "insert-light-source-option-unknown",
       f"insert {INS} --light-source sky --light-text noon --light-source-option foo=1 --out o.png",
       words="`--light-source-option`"),
    _c(G, "insert-light-source-sky",
       f"insert {INS} --light-source sky --light-text noon,from,the,left --out o.png",
       expect="handle"),
    _c(G, "relight-rgb-jpeg", f"relight {{F}}/photo.jpg {LIGHT} --out o.png", expect="handle"),
    # --- gaffer-nerf --------------------------------------------------------------------------
    _c(N, "fit-missing", "fit {F}/missing --out fit"),
    _c(N, "fit-empty", "fit {F}/emptydir --out fit"),
    _c(N, "fit-into-file", "fit {F}/emptydir --out {F}/afile/fit"),
    _c(N, "fit-iterations-0", "fit {F}/emptydir --out fit --iterations 0"),
    _c(N, "fit-batch-rays-absurd", "fit {F}/emptydir --out fit --batch-rays 100000000"),
    _c(N, "fit-device-cuda", "fit {F}/emptydir --out fit --device cuda"),
    _c(N, "render-garbage-field", "render {F}/field --data {F}/emptydir --out ren"),
    _c(N, "render-orbit-0", "render {F}/field --data {F}/emptydir --out ren --orbit 0"),
    _c(N, "relight-text-envmap",
       "relight {F}/field --data {F}/emptydir --envmap {F}/text.exr --out rel"),
    _c(N, "evaluate-json-into-file",
       "evaluate {F}/field --data {F}/emptydir --json {F}/afile/r.json"),
    _c(N, "fit-out-file", "fit {F}/nerfdata --out {F}/afile", words="`--out`"),
    _c(N, "fit-out-empty", "fit {F}/nerfdata --out ''", words="argument --out: is empty"),
    _c(N, "evaluate-json-fifo",
       "evaluate {F}/goodfield --data {F}/nerfdata --target-lighting 0 --json {F}/fifo.json",
       words="not a regular file"),
    _c(N, "evaluate-json-empty",
       "evaluate {F}/goodfield --data {F}/nerfdata --target-lighting 0 --json ''",
       words="argument --json: is empty"),
    _c(N, "fit-slot-folder", "fit {F}/nerfdata --out {F}/slots", words="field.safetensors is a"),
    _c(N, "relight-out-file",
       "relight {F}/goodfield --data {F}/nerfdata --target-lighting 0 --out {F}/afile",
       words="`--out`"),
    _c(N, "relight-out-is-field",
       "relight {F}/goodfield --data {F}/nerfdata --target-lighting 0 --out {F}/goodfield",
       words="is the input `field`"),
    _c(N, "relight-slot-file",
       "relight {F}/goodfield --data {F}/nerfdata --target-lighting 0 --out {F}/viewslot",
       words="relit_views is a file"),
    _c(N, "render-out-file", "render {F}/goodfield --data {F}/nerfdata --out {F}/afile",
       words="`--out`"),
    _c(N, "render-slot-folder", "render {F}/goodfield --data {F}/nerfdata --out {F}/slots",
       words="000.png is a folder"),
    _c(N, "evaluate-json-folder",
       "evaluate {F}/goodfield --data {F}/nerfdata --target-lighting 0 --json {F}/emptydir",
       words="`--json`"),
    _c(N, "evaluate-pred-dir-file",
       "evaluate {F}/goodfield --data {F}/nerfdata --target-lighting 0 --pred-dir {F}/afile",
       words="`--pred-dir`"),
]  # fmt: skip

if not any(Path("/dev").glob("nvidia[0-9]*")):
    CASES.append(_c(G, "relight-device-cuda", f"relight {{F}}/good.png {LIGHT} --out o.png --device cuda"))  # fmt: skip


def _write_files(folder: Path) -> None:
    """The collection of bad (and a few good) files every row reads from, as absolute paths."""
    from PIL import Image

    from gaffer_envmap.bundled import bundled_hdris
    from gaffer_envmap.environment_map import EnvironmentMap
    from gaffer_envmap.io import write_envmap

    folder.mkdir(parents=True, exist_ok=True)
    city = bundled_hdris()["city"]
    (folder / "city.exr").write_bytes(city.read_bytes())
    (folder / "empty.exr").write_bytes(b"")
    (folder / "text.exr").write_text("not an EXR\n")
    (folder / "text.hdr").write_text("not a Radiance HDR\n")
    (folder / "truncated.exr").write_bytes(city.read_bytes()[: city.stat().st_size // 2])
    nan = np.full((16, 32, 3), 0.5, np.float32)
    nan[3, 4] = np.nan
    _write_exr(folder / "nan.exr", nan)
    (folder / "maps").mkdir()
    write_envmap(folder / "maps" / "grey.exr", EnvironmentMap(radiance_linear=np.full((16, 32, 3), 0.5, np.float32)))  # fmt: skip
    (folder / "wide").mkdir()
    _write_exr(folder / "wide" / "wide.exr", np.full((16, 48, 3), 0.5, np.float32))  # 3:1
    w2c = np.concatenate([np.eye(3), [[0.0], [0.0], [-2.0]]], axis=1)
    np.save(folder / "w2c.npy", w2c)
    np.save(folder / "w2c_strings.npy", np.array(["a", "b", "c"]))
    np.save(folder / "w2c_empty.npy", np.zeros((0,)))
    np.save(folder / "w2c_pickle.npy", np.array([{"a": 1}], dtype=object), allow_pickle=True)
    np.save(folder / "w2c_nan.npy", np.full((3, 4), np.nan))
    (folder / "w2c_text.npy").write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n")
    rgba = np.zeros((40, 30, 4), np.uint8)
    rgba[8:32, 6:24] = (200, 120, 80, 255)
    Image.fromarray(rgba).save(folder / "good.png")
    Image.fromarray(np.zeros((1, 1, 4), np.uint8)).save(folder / "tiny.png")
    (folder / "garbage.png").write_text("not a PNG")
    (folder / "empty.png").write_bytes(b"")
    gray = (np.linspace(0, 65535, 40 * 30).reshape(40, 30)).astype(np.uint16)
    Image.fromarray(gray).save(folder / "gray16.png")  # 16-bit grayscale
    mask = np.zeros((40, 30), np.uint8)
    mask[8:32, 6:24] = 255
    Image.fromarray(mask).save(folder / "mask.png")
    (folder / "afile").write_text("a file where a folder is expected\n")
    (folder / "garbage.json").write_text("{not json")
    (folder / "emptydir").mkdir()
    (folder / "unrelated").mkdir()
    (folder / "unrelated" / "notes.txt").write_text("not a dataset")
    (folder / "field").mkdir()
    (folder / "field" / "field.safetensors").write_bytes(b"\x00garbage" * 8)
    (folder / "field" / "field.json").write_text("{not json")
    _write_output_clashes(folder)


def _write_output_clashes(folder: Path) -> None:
    """`slots/` holds a folder in the place of each file the commands write into an
    output folder, and a file in the place of each sub-folder; a real field header and a multi-view
    folder whose checks pass (so the output is what is refused); photos without a usable alpha."""
    import json

    from PIL import Image

    slots = folder / "slots"
    for name in ("ldr.png", "proc_0000.exr", "overview.png", "dataset.json", "o.mask.png",
                 "t_000.png", "q_mask.png", "field.safetensors", "000.png"):  # fmt: skip
        (slots / name).mkdir(parents=True)
    for name in ("objects", "unet"):
        (slots / name).write_text("a file where a folder is expected\n")
    (folder / "viewslot").mkdir()
    os.mkfifo(folder / "fifo.png")  # not a regular file: a rename over it would replace the node
    os.mkfifo(folder / "fifo.json")
    (folder / "ldrmap").mkdir()
    Image.fromarray(np.full((8, 16, 3), 128, np.uint8)).save(folder / "ldrmap" / "ldr.png")
    (folder / "viewslot" / "relit_views").write_text("a file where a folder is expected\n")
    field = folder / "goodfield"
    field.mkdir()
    (field / "config.json").write_text(json.dumps({"_class_name": "TensoRFVM"}))
    header = json.dumps({"w": {"dtype": "F32", "shape": [1], "data_offsets": [0, 4]}}).encode()
    (field / "field.safetensors").write_bytes(len(header).to_bytes(8, "little") + header + bytes(4))
    data = folder / "nerfdata"
    data.mkdir()
    meta = {
        "frames": [{"file_path": "x", "lit": [{"lighting_index": 0, "file_path": "x"}]}],
        "lightings": [{"lighting_index": 0, "envmap": "a"}],
    }
    for split in ("train", "test"):
        (data / f"transforms_{split}.json").write_text(json.dumps(meta))
    config = {"output_dir": str(folder / "afile"), "data": {"root": str(folder / "emptydir")}}
    (folder / "train_into_file.json").write_text(json.dumps(config))
    yy, xx = np.mgrid[:60, :80]
    disc = (yy - 30) ** 2 + (xx - 40) ** 2 < 18**2
    rgb = np.empty((60, 80, 3), np.uint8)
    rgb[...] = (90, 140, 200)
    rgb[disc] = (220, 120, 40)
    Image.fromarray(rgb).save(folder / "photo.jpg", quality=95)
    Image.fromarray(np.dstack([rgb, np.full((60, 80), 255, np.uint8)])).save(folder / "opaque.png")


def _write_exr(path: Path, rgb: np.ndarray) -> None:
    """A float32 EXR as is (gaffer-envmap's own writer refuses NaN and maps that are not 2:1)."""
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"RGB": rgb}) as f:
        f.write(str(path))


_RUNNER = textwrap.dedent(
    r"""
    import contextlib, importlib, io, json, logging, os, resource, sys, traceback
    resource.setrlimit(resource.RLIMIT_AS, (int(sys.argv[3]), int(sys.argv[3])))
    module, rows = sys.argv[1], json.loads(open(sys.argv[2]).read())
    main = importlib.import_module(module).main
    results = {}
    for row in rows:
        os.makedirs(row["cwd"], exist_ok=True)
        os.chdir(row["cwd"])
        err, out = io.StringIO(), io.StringIO()
        for h in list(logging.root.handlers):  # basicConfig binds again, to the captured stderr
            logging.root.removeHandler(h)
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
            try:
                rc = main(row["argv"])
            except SystemExit as exc:  # argparse
                rc = exc.code if isinstance(exc.code, int) else 1
            except BaseException:  # what a user would see: a traceback
                err.write(traceback.format_exc())
                rc = 1
        results[row["id"]] = {"rc": rc, "err": err.getvalue(), "out": out.getvalue()[-2000:]}
    print(json.dumps(results))
    """
)


def _run_all(folder: Path, cases: list[Case]) -> dict[str, dict]:
    procs = {}
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", HF_HUB_OFFLINE="1")
    env["TRANSFORMERS_OFFLINE"] = "1"
    for cli, module in MODULES.items():
        rows = [
            {
                "id": c.id,
                "cwd": str(folder / "cwd" / c.id.replace(":", "_")),
                "argv": [a.replace("{F}", str(folder)).replace("''", "") for a in c.argv],
            }
            for c in cases
            if c.cli == cli
        ]
        if not rows or importlib.util.find_spec(module.split(".")[0]) is None:
            continue
        table = folder / f"rows_{cli}.json"
        table.write_text(json.dumps(rows))
        procs[cli] = subprocess.Popen(
            [sys.executable, "-c", _RUNNER, module, str(table), str(MEMORY_CAP)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
    results: dict[str, dict] = {}
    for cli, proc in procs.items():
        out, err = proc.communicate(timeout=240)
        try:
            results.update(json.loads(out.strip().splitlines()[-1]))
        except (ValueError, IndexError):
            for c in cases:
                if c.cli == cli:
                    results[c.id] = {"rc": None, "err": f"runner died: {err[-3000:]}", "out": ""}
    return results


def _error_lines(err: str) -> list[str]:
    """The lines that report an error: not blank, not argparse's usage (and its indented
    continuation), not a log record of level INFO/WARNING/DEBUG."""
    lines = []
    for ln in err.splitlines():
        if not ln.strip() or ln.startswith(("usage:", " ")):
            continue
        if ln.split(" ", 1)[0].rstrip(":") in ("INFO", "WARNING", "DEBUG"):
            continue
        lines.append(ln)
    return lines


def classify(case: Case, r: dict, cwd: Path) -> str:
    """`refused` / `handled` (what is wanted) or what went wrong: `traceback`, `silent` (a bad input
    accepted, exit 0), `failed` (an edge case refused), `unclear` (not one error line), `partial`
    (something written)."""
    err = r["err"] or ""
    if r["rc"] is None or "Traceback" in err:
        return "traceback"
    if case.expect == "handle":
        return "handled" if r["rc"] == 0 else "failed"
    if r["rc"] == 0:
        return "silent"
    left = sorted(p.name for p in cwd.iterdir()) if cwd.exists() else []
    if left:
        return "partial"
    lines = _error_lines(err)
    if len(lines) != 1 or (case.words and case.words not in lines[0]):
        return "unclear"
    return "refused"


_SUMMARY: dict[str, list[str]] = {}


@pytest.fixture(scope="module")
def fuzz(tmp_path_factory, request):
    folder = tmp_path_factory.mktemp("fuzz")
    _write_files(folder)
    results = _run_all(folder, CASES)
    yield folder, results
    reporter = request.config.pluginmanager.get_plugin("terminalreporter")
    counts: dict[str, int] = {}
    for outcome in _SUMMARY.values():
        counts[outcome[0]] = counts.get(outcome[0], 0) + 1
    line = ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
    text = f"bad-input suite: {len(_SUMMARY)} tries: {line}"
    bad = [f"  {cid}: {o[0]}: {o[1]}" for cid, o in sorted(_SUMMARY.items())]
    bad = [b for b in bad if ": refused:" not in b and ": handled:" not in b]
    capture = request.config.pluginmanager.get_plugin("capturemanager")
    with capture.global_and_fixture_disabled() if capture is not None else contextlib.nullcontext():
        if reporter is not None:
            reporter.ensure_newline()
            reporter.write_sep("-", "bad-input suite")
            reporter.write_line(text)
            for b in bad:
                reporter.write_line(b[:300])
        else:
            print(text, *bad, sep="\n")


def _param(c: Case):
    marks = list(c.marks)
    if c.xfail:
        marks.append(pytest.mark.xfail(reason=c.xfail, strict=False))
    return pytest.param(c, id=c.id, marks=marks)


@pytest.mark.parametrize("case", [_param(c) for c in CASES])
def test_bad_input(fuzz, case: Case) -> None:
    folder, results = fuzz
    if case.id not in results:
        pytest.skip(f"{MODULES[case.cli]} is not installed")
    r = results[case.id]
    cwd = folder / "cwd" / case.id.replace(":", "_")
    outcome = classify(case, r, cwd)
    first = (_error_lines(r["err"] or "") or [""])[-1]
    _SUMMARY[case.id] = [outcome, first[:200] if outcome != "refused" else ""]
    want = "handled" if case.expect == "handle" else "refused"
    assert outcome == want, f"{outcome}: rc {r['rc']}, stderr:\n{(r['err'] or '')[-1500:]}"
