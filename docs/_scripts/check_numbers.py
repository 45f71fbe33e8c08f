"""Check that every measured number in the project's prose comes from a committed result file (issue 34).

Runnable alone (`python docs/_scripts/check_numbers.py [FILE ...]`, exit 1 on a failure) and run by
`tests/test_doc_numbers.py` in the normal pytest run.

What it reads: README.md, every `docs/**/*.md`, `benchmarks/README.md`, every package's and
integration's README.md and every shipped model card (`MODEL_CARD.md`). Changelogs are history (what a
release measured then) and are not read.

Sources. A page declares where its numbers come from in an HTML comment (not rendered):

    <!-- numbers-from: benchmarks/results/nerf.json benchmarks/results/nerf_real.json -->

A declaration before the page's first heading covers the whole page; one under a heading covers that
section and its subsections (until the next heading of the same or a higher level). Paths are relative to
the repository root; each names one JSON file, which contributes every numeric leaf (a directory of
per-pair files would match almost any number by chance, so it is refused).

What counts as a measured number (`measured_numbers`): outside code (fenced blocks, inline code), HTML
comments and link targets,

- a decimal (`15.84`, `0.2382`), except versions (two dots, after a name such as `gaffer-tiny`,
  `torch`, `Python`, or a bare shipped-model release, `RELEASE_VERSIONS`), dimensions (`512×256`),
  and scientific notation without a unit (`8e-6`, `1e-4`: weights, rates and thresholds, settings);
- a number with a unit of measure: dB, s / ms / min / h / seconds, %, a ratio (`24x`, `1.9×`), decimal
  degrees (`22.12 degrees`; whole degrees are angles one sets), sizes (MB, MiB, GB, GiB, KiB), rates
  (`it/s`, `maps/s`, `images/s`, `fps`). Counts (`3.8M` parameters, `495 pairs`) are not measurements.
  A unit wrapped onto the next line of the paragraph (`about 1.5` / `minutes`) is the number's unit.

Settings are written without such a unit (`128 px`, `50 steps`, `300 iterations`, `16 samples`), in
code (`--threads 2`), or listed in `NOT_MEASURED` below with the reason.

When a number matches (`_matches`): the number, as written, equals a leaf of a declared source rounded to
the shown precision (`15.84` matches 15.8412; `3,519 s` matches 3518.83). Derived forms, each narrow:

- percentages: `87%` also matches a fraction leaf 0.8712 (x 100);
- time units: a leaf in seconds shown in ms (x 1000) or minutes (/ 60), a leaf in ms shown in s;
- a signed difference (`+3.91 dB`, `-0.03 dB`, written with its sign), or a gap in dB (`0.43 dB
  below`: |a - b|), matches a - b, and a ratio
  (`24x`, `1.27×`) matches a / b, where a and b are leaves of ONE declared file at sibling paths: the
  same path except for one dict key (the variant: `summary.transfer.psnr` vs `summary.resize.psnr`,
  `rows[3].theirs` vs `rows[3].ours`), never two list entries (per-pair rows) or two files. A text can
  always show the two operands instead.

Pins. A number can be tied to ONE leaf, so that it must equal that value and no other of its
section's files:

    The transfer scores 17.76 dB. <!-- pin: 17.76 dB = benchmarks/results/detail_transfer.json#summary.transfer.psnr -->

    <!-- pin: 18.37 dB = benchmarks/results/x.json#means.relit.psnr; +3.91 dB = benchmarks/results/x.json#a.psnr - #b.psnr -->
    A paragraph that states 18.37 dB and +3.91 dB.

A pin covers the paragraph it stands in: the run of non-blank lines around it (write it at the end of
one of the paragraph's lines, or on its own line directly above or below the paragraph, with no blank
line between). One comment may hold several pins, separated by `;`. The left side is the number as
the page writes it (its sign, and its unit or none); the right side is a JSON file, `#` and a key path
(keys between dots, list indexes as numbers: `rows.2.object_psnr_raw`), or two such leaves with ` - `
or ` / ` (spaces around) between them, where the second may leave out its file (`#key`: the same
file). Every number of the paragraph written as the pin's left side is then checked against that
value only, at its shown precision (with the unit's scaling: a percent of a fraction, seconds shown
in ms, minutes or hours); a pin overrides the section's sources and the allowlists for its number.
A pin fails when its file is not a JSON file, its path names no number, its number is not among the
paragraph's measured numbers, or the value differs.

How strict this is: an unpinned number is checked against every leaf of its section's files, so a
wrong number can still pass when it happens to equal another value there (pins close that gap). Measured on random numbers
(2026-12-06): a 2-decimal dB value in 10-30 passes by chance against the NeRF validation files about 1
time in 10, a 4-decimal ST-LPIPS almost never, a signed dB difference against a file with many variants
(nerf_real.json's 12) often; against the model card's summary rows, rarely. Narrow sections and
specific files keep it useful; it catches a number that went stale, not every typo. Headline numbers
(README's hand-written text, the tutorials' own runs) are pinned.

A number written after "about" must still match at its shown precision ("about" tells the reader that
it was rounded, not that it may differ).

Generated blocks are accepted through their generator: the model card's `<!-- table: NAME -->`
blocks and README's `<!-- generated: gaffer-tiny-headline -->` block are rebuilt here by
`benchmarks/gaffer_tiny_card.py` from `benchmarks/results/reshade/` and must equal it byte for byte;
benchmarks/README.md's `<!-- BEGIN name -->` blocks (written by `--update-baseline` from
`results/<name>.json`) are checked against that file like any text.

A failure names file:line, the number and why (no source declared, or no source value matches).
"""

import argparse
import functools
import importlib.util
import json
import math
import re
import sys
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[2]

# Non-measured constants that read like measurements, per file, each with its reason. Keep this short:
# a number that was measured belongs in a result file, not here.
_FRAMING = "the object-centred framing (the object spans 75% of the crop): a setting"
NOT_MEASURED: dict[str, dict[str, str]] = {
    "README.md": {
        "3 minutes": "the smoke_train session's time budget (a setting)",
        "+4.5 dB": "issue 31's target (raw object PSNR over the input)",
        "+3 dB": "issue 31's target (aligned object PSNR over the input)",
    },
    "benchmarks/README.md": {
        "30×": "issue 18's goal for the default encoding (a target, not a measurement)",
        "5×": "issue 18's goal for compat (a target, not a measurement)",
    },
    "docs/app.md": {"20 MB": "the default upload limit (`--max-upload-mb`), a setting"},
    "docs/cli.md": {"0.53": "the sun disc's angular size (the real sun's), a constant of the sky"},
    "docs/conventions.md": {
        "0.00": "u coordinates of the layout (definitions)",
        "1.00": "u coordinates of the layout (definitions)",
        "0.25": "u coordinates of the layout (definitions)",
        "0.50": "u coordinates of the layout (definitions)",
        "0.75": "u coordinates of the layout (definitions)",
    },
    "docs/encodings.md": {
        "0.75": "the authors' preprocessing divides by 0.75 (the object spans 75%): a constant",
        "99.9 %": "the tests' threshold (a setting of the test, not a measurement)",
        "0.18215": "Stable Diffusion's VAE scaling factor, a constant of the authors' model",
    },
    "docs/installation.md": {"3.11": "CPython 3.11, a version"},
    "docs/tutorials/insert.md": {
        "39.6 degrees": "the default field of view (Blender's 50 mm lens), a setting",
        "39.6": "the default field of view (Blender's 50 mm lens), a setting",
        "0.53": "the sun's angular diameter, a constant",
    },
    "docs/tutorials/skies.md": {
        "51.48": "Greenwich's latitude, a constant",
        "23.44": "the Earth's axial tilt, a constant",
        "61.96 degrees": "arithmetic on the two constants before it",
        "2.5": "the grammar's clear-sky turbidity, a setting",
        "0.53": "the sun's angular diameter, a constant",
        "133.8": "the extraterrestrial illuminance (klx), a physical constant",
        "2.5 degrees": "the night model's dimming step, a constant of the code",
    },
    "docs/tutorials/relight-photo.md": {
        "75%": _FRAMING,
        "0.01": "the epsilon of the shading ratio, a constant of the code",
        "39.6 degrees": "the default field of view (Blender's 50 mm lens), a setting",
    },
    "docs/tutorials/train.md": {
        "0.9": "AdamW betas of the authors' recipe (configs/neural-gaffer-paper.json)",
        "0.999": "AdamW betas of the authors' recipe (configs/neural-gaffer-paper.json)",
        "0.05": "CFG dropout of the authors' recipe (a setting)",
        "10%": "area-light input share of the authors' recipe (a setting)",
    },
    "integrations/comfyui/README.md": {"0.18": "the preview's middle grey (tone-mapping constant)"},
    "packages/gaffer-data/README.md": {
        "1.5": "the paper's camera distance range U(1.5, 2.2), a setting",
        "2.2": "the paper's camera distance range U(1.5, 2.2), a setting",
        "0.35": "the grey world of the area-light render, a setting",
        "1 MiB": "the OBJ reader's chunk size, a setting",
        "2.60": "ray's version",
        "2 GiB": "the default worker memory cap, a setting",
        "4096 MB": "the default worker memory cap, a setting",
    },
    "packages/gaffer-diffusion/README.md": {
        "0.18215": "Stable Diffusion's VAE scaling factor, a constant of the authors' model",
        "75%": _FRAMING,
        "5x": "issue 4's speed target",
        "50 ms": "issue 4's latency target",
        "+4.5": "issue 31's target (raw object PSNR over the input)",
        "+3 dB": "issue 31's target (aligned object PSNR over the input)",
    },
    "packages/gaffer-diffusion/src/gaffer_diffusion/weights/gaffer-normals/MODEL_CARD.md": {
        "75%": _FRAMING,
    },
    "packages/gaffer-envmap/README.md": {
        "0.53": "the sun disc's angular size (the real sun's), a constant of the sky",
    },
    "packages/gaffer-nerf/README.md": {
        "0.02": "the paper's learning rate (relight_preset('paper')), a setting",
        "0.99": "the paper's Adam beta, a setting",
        "0.9": "the paper's Adam beta, a setting",
        "-1.4": "the paper's bounding box +-1.4, a setting",
        "0.1": "the learning-rate decay factor, a setting",
        "0.25": "rank selection's default tolerance (`tolerance_db`), a setting",
        "0.25 dB": "rank selection's default tolerance (`tolerance_db`), a setting",
        "3 dB": "the rank-selection test's tolerance, a setting of the test",
        "60 s": "the end-to-end test's time limit, a setting of the test",
        "3 min": "the paper's reported Stage 2 time (its text), not measured here",
        "2 min": "issue 6's target, not a measurement",
    },
}

# Release versions of the shipped models (gaffer-tiny 0.2-0.7, gaffer-normals 1.0-1.1; their
# manifests and cards): prose names them bare ("against 0.4"), so a bare decimal equal to one, with no
# unit after it, is read as a version. A measured value that happens to equal one goes unchecked.
RELEASE_VERSIONS = frozenset({"0.2", "0.3", "0.4", "0.5", "0.6", "0.7", "1.0", "1.1"})


def pages(root: Path = ROOT) -> list[Path]:
    """Every Markdown file whose numbers are checked."""
    found = [root / "README.md", root / "benchmarks" / "README.md"]
    # `_generated/` fragments are written from the JSON files at build time; `_build/` is output
    found += sorted(
        p
        for p in (root / "docs").rglob("*.md")
        if not {"_build", "_generated"} & set(p.relative_to(root).parts)
    )
    found += sorted((root / "packages").glob("*/README.md"))
    found += sorted((root / "integrations").glob("*/README.md"))
    found += sorted((root / "packages").glob("*/src/*/weights/*/MODEL_CARD.md"))
    return [p for p in found if p.is_file()]


# ---------------------------------------------------------------------------------------------
# Reading a page: prose lines, declarations, generated blocks
# ---------------------------------------------------------------------------------------------
_DECL = re.compile(r"<!--\s*numbers-from:\s*(.*?)\s*-->", re.S)
_HEADING = re.compile(r"^(#{1,6})\s")
_FENCE = re.compile(r"^\s*(```+|~~~+)(.*)$")
_GENERATED_OPEN = re.compile(r"<!--\s*(table|generated):\s*([\w.-]+)\s*-->")
_GENERATED_CLOSE = re.compile(r"<!--\s*/(table|generated)\s*-->")


_PIN_COMMENT = re.compile(r"<!--\s*pin:(.*?)-->", re.S)
_LEAF = r"[^\s#]*#[^\s]+"
_PIN_EXPR = re.compile(rf"^(?P<a>{_LEAF})(?:\s+(?P<op>[-/])\s+(?P<b>{_LEAF}))?$")


@dataclass(frozen=True)
class Line:
    """One line of prose with what covers it."""

    number: int  # 1-based
    text: str  # code, comments and link targets blanked out
    sources: tuple[str, ...]  # declared source paths in scope
    paragraph: int = 0  # index of its run of non-blank lines (what a pin covers)
    continues: str = ""  # the start of the next line of its paragraph (a unit wrapped onto it)


@dataclass(frozen=True)
class Pin:
    """`<!-- pin: NUMBER = FILE#PATH [- or / [FILE]#PATH] -->`: one number tied to one value."""

    line: int
    paragraph: int
    left: str  # the number as the page writes it
    right: str  # the leaf expression


@dataclass(frozen=True)
class Page:
    """What `read_page` finds: prose lines, generated blocks `(line, kind, name)` and pins."""

    lines: list[Line]
    generated: list[tuple[int, str, str]]
    pins: list[Pin]


def _pins_in(comment: str, line: int, paragraph: int) -> list[Pin]:
    found = []
    for part in comment.split(";"):
        if part.strip():
            left, _, right = part.partition("=")
            found.append(Pin(line, paragraph, left.strip(), right.strip()))
    return found


def _blank_code_and_links(text: str) -> str:
    text = re.sub(r"`[^`]*`", " ", text)  # inline code: commands, flags, settings
    text = re.sub(r"\]\([^)]*\)", "] ", text)  # link targets
    text = re.sub(r"https?://\S+", " ", text)
    text = re.sub(r"\{[a-z]+\}`[^`]*`", " ", text)  # MyST roles
    return text


def read_page(path: Path) -> Page:
    """The page's prose lines (with declared sources in scope), its generated blocks and its pins."""
    raw = path.read_text().splitlines()
    pins: list[Pin] = []
    paragraph = 0
    pin_open: tuple[int, str] | None = None  # a pin comment that goes on over lines
    # declarations: (line index, heading level in force or 0 for page-wide, paths)
    lines: list[Line] = []
    generated: list[tuple[int, str, str]] = []
    scopes: list[tuple[int, tuple[str, ...]]] = []  # stack of (heading level, sources)
    page_sources: tuple[str, ...] = ()
    level = 0
    in_fence: str | None = None
    in_comment = False
    in_generated = False
    directives: list[str] = []  # open MyST directive fences ({important}, {note}): prose inside
    for i, line in enumerate(raw, start=1):
        if not line.strip():
            paragraph += 1
        fence = _FENCE.match(line)
        if in_fence is not None:
            if fence and fence.group(1).startswith(in_fence) and not fence.group(2).strip():
                in_fence = None
            continue
        if fence:
            info = fence.group(2).strip()
            if not info and directives and fence.group(1).startswith(directives[-1]):
                directives.pop()  # the directive's closing fence
                continue
            if info.startswith("{") and info not in ("{code-block}", "{code}"):
                if not info.startswith(("{include}", "{image}", "{figure}", "{literalinclude}")):
                    directives.append(fence.group(1))
                    continue
                in_fence = fence.group(1)  # an include's options: a path, no prose
                continue
            in_fence = fence.group(1)  # code: commands and settings
            continue
        m = _HEADING.match(line)
        if m:
            level = len(m.group(1))
            scopes = [s for s in scopes if s[0] < level]
        if pin_open is not None:
            start, text = pin_open
            text += "\n" + line
            if "-->" in line:
                whole = _PIN_COMMENT.search(text)
                pins += _pins_in(whole.group(1), start, paragraph) if whole else []
                pin_open = None
            else:
                pin_open = (start, text)
        else:
            for c in _PIN_COMMENT.finditer(line):
                pins += _pins_in(c.group(1), i, paragraph)
            tail = _PIN_COMMENT.sub(" ", line)
            if re.search(r"<!--\s*pin:", tail):
                pin_open = (i, tail[tail.index("<!--") :])
        for d in _DECL.finditer(line):
            declared = tuple(d.group(1).split())
            if level == 0:
                page_sources += declared
            else:
                scopes.append((level, declared))
        g = _GENERATED_OPEN.search(line)
        if g:
            generated.append((i, g.group(1), g.group(2)))
            in_generated = True
        if _GENERATED_CLOSE.search(line):
            in_generated = False
            continue
        if in_generated:
            continue
        # HTML comments, also across lines
        text = line
        if in_comment:
            if "-->" not in text:
                continue
            text = text.split("-->", 1)[1]
            in_comment = False
        text = re.sub(r"<!--.*?-->", " ", text)
        if "<!--" in text:
            text = text.split("<!--", 1)[0]
            in_comment = True
        if m:
            text = text[len(m.group(1)) :]
        sources = page_sources + tuple(p for _, ps in scopes for p in ps)
        lines.append(Line(i, _blank_code_and_links(text), sources, paragraph))
    # a number at the end of a line whose unit was wrapped onto the next ("about 1.5\nminutes")
    lines = [
        replace(a, continues=b.text[:24])
        if b.number == a.number + 1 and b.paragraph == a.paragraph
        else a
        for a, b in zip(lines, [*lines[1:], Line(0, "", ())], strict=True)
    ]
    return Page(lines, generated, pins)


# ---------------------------------------------------------------------------------------------
# Finding measured numbers
# ---------------------------------------------------------------------------------------------
_UNIT = (
    r"(?P<unit>dB|ms|µs|us|s|sec|seconds?|min|minutes?|h|hours?|%|x|×|°|deg|degrees?"
    r"|MB|MiB|GB|GiB|KiB|kB|it/s|maps/s|images/s|img/s|fps|M)"
)
_NUMBER = re.compile(
    r"(?<![\w.\-/])(?P<sign>[+\-−]?)(?P<num>\d{1,3}(?:,\d{3})+(?:\.\d+)?|\d+(?:\.\d+)?(?:e[+\-−]?\d+)?)"
    r"(?:\s?" + _UNIT + r")?(?![\w/])"
)
# a name before a version number
_VERSION_BEFORE = re.compile(
    r"(?:gaffer-[a-z]+|torch|PyTorch|Python|python|Blender|bpy|numpy|diffusers|transformers|CUDA|"
    r"version|release|v|Release|releases|SD|ruff|gradio|ComfyUI|Pillow|OpenEXR|Cycles|schema|"
    r"ViT-L/|cuDNN|macOS|Ubuntu|[≥≤<>=~^]=?)\s*$"
)


@dataclass(frozen=True)
class Number:
    """A measured-looking number found in prose."""

    line: int
    text: str  # as written, with sign and unit
    value: float  # without sign
    decimals: int
    sign: str  # "+", "-" or ""
    unit: str


def _is_version_context(before: str, after: str) -> bool:
    if re.match(r"\.\d", after):  # 2.13.0, 0.5.1
        return True
    return bool(_VERSION_BEFORE.search(before[-24:])) and not after.lstrip().startswith(
        ("dB", "s ", "ms", "%")
    )


def measured_numbers(line: Line) -> Iterator[Number]:
    text = line.text
    for m in _NUMBER.finditer(text):
        num, unit, sign = m.group("num"), m.group("unit") or "", m.group("sign")
        before, after = text[: m.start()], text[m.end() :]
        if not unit and not after.strip() and line.continues:
            wrapped = re.match(r"\s*" + _UNIT + r"(?![\w/])", line.continues)
            if wrapped and wrapped.group("unit") not in ("x", "×", "M"):
                unit = wrapped.group("unit")
        if unit in ("x", "×") and not re.search(r"\d[x×]$", m.group(0)):
            unit = ""  # "50 x UNet": a count times something, not a ratio (ratios: 24x, 1.9×)
        # dimensions and products of settings: 512×256, 64x64, 2x2
        if unit in ("x", "×") and re.match(r"\s?\d", after):
            continue
        if re.search(r"\d\s?[x×]\s?$", before):
            continue
        # dates and times: 2026-12-04, 20:50
        if re.search(r"\d[-:]$", before) or re.match(r"[-:]\d", after):
            continue
        # section, issue and equation numbers: §4.2, issue 18, Sec. 3.1, Eq. 3, step 1000
        if re.search(
            r"(§|[Ss]ec\.?|[Ss]ection|[Ee]q\.?|[Ii]ssue|#|Table|Fig\.?|[Ff]igure)\s*$", before
        ):
            continue
        decimal = "." in num or "e" in num
        if not decimal and not unit:
            continue  # counts and settings: 50 steps, 128 px, 3 views
        if unit == "M":
            continue  # counts of parameters or values (3.8M), facts of a file, not measurements
        if "e" in num and not unit:
            continue  # 8e-6, 1e-4: weights, rates and thresholds (settings) in this project's prose
        if unit in ("°", "deg", "degree", "degrees") and not decimal:
            continue  # 45 degrees, 15 deg: angles one sets (light elevation, field of view)
        if decimal and not unit and _is_version_context(before, after):
            continue
        if not unit and not sign and num in RELEASE_VERSIONS:
            continue
        if unit == "s" and re.match(r"['’]", after):
            continue
        clean = num.replace(",", "").replace("−", "-")
        mantissa = clean.split("e")[0]
        decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
        if "e" in clean:
            # 4e-9: compare in significant digits of the exponent form
            decimals = -1
        yield Number(
            line.number,
            m.group(0).strip() if m.group("unit") or not unit else f"{m.group(0).strip()} {unit}",
            float(clean),
            decimals,
            {"+": "+", "-": "-", "−": "-"}.get(sign, ""),
            unit,
        )


# ---------------------------------------------------------------------------------------------
# Sources and matching
# ---------------------------------------------------------------------------------------------
Path_ = tuple[str | int, ...]


def _leaves(value: object, path: Path_ = ()) -> Iterator[tuple[Path_, float]]:
    if isinstance(value, bool):
        return
    if isinstance(value, int | float):
        if math.isfinite(value):
            yield path, float(value)
    elif isinstance(value, dict):
        for k, v in value.items():
            yield from _leaves(v, (*path, str(k)))
    elif isinstance(value, list):
        for k, v in enumerate(value):
            yield from _leaves(v, (*path, k))


@functools.cache
def source_leaves(source: str) -> tuple[tuple[Path_, float], ...]:
    """Every numeric leaf of one declared JSON file."""
    return tuple(_leaves(json.loads((ROOT / source).read_text())))


def _shown(value: float, decimals: int) -> float:
    return round(value, decimals) if decimals >= 0 else float(f"{value:.0e}")


def _equal_at(candidate: float, n: Number) -> bool:
    if n.decimals < 0:  # 4e-9 and the like: same leading digit and exponent
        return candidate != 0 and f"{abs(candidate):.0e}" == f"{n.value:.0e}"
    # within half a unit of the last shown digit: either rounding of an exact tie (38.25 -> 38.2 or
    # 38.3) is accepted
    return abs(abs(candidate) - n.value) <= 0.5 * 10 ** (-n.decimals) * (1 + 1e-9)


_SCALES = {
    "%": (1.0, 100.0),
    "ms": (1.0, 1000.0),
    "s": (1.0, 0.001),
    "sec": (1.0, 0.001),
    "seconds": (1.0, 0.001),
    "second": (1.0, 0.001),
    "min": (1.0, 1 / 60),
    "minutes": (1.0, 1 / 60),
    "minute": (1.0, 1 / 60),
    "h": (1.0, 1 / 3600),
    "hours": (1.0, 1 / 3600),
    "hour": (1.0, 1 / 3600),
}


# A number with a unit matches only leaves whose path names that kind of quantity (a "17×" must not
# match a 17.18 ms timing): the path, lowercased, must match the unit's pattern.
_KIND = {
    "dB": r"psnr|db|gain",
    "x": r"ratio|speedup|vs_|_vs|times|factor|x_|floor|guard|tolerance",
    "°": r"deg|angle|angular",
    "time": r"(^|[._ ])(s|ms|sec|secs|seconds?|time|wall|latency|duration)([._ ]|$)|_s$|_ms$|_s[._]"
    r"|seconds|_ms|ms_|time|phase|^s_|\.s_",
    "size": r"mib|mb|gib|gb|bytes|memory|size",
    "rate": r"per_s|_s$|throughput|fps|it_s|images|maps",
}
_UNIT_KIND = {
    "dB": "dB",
    "x": "x",
    "×": "x",
    "°": "°",
    "deg": "°",
    "degree": "°",
    "degrees": "°",
    **dict.fromkeys(
        ("ms", "µs", "us", "s", "sec", "second", "seconds", "min", "minute", "minutes", "h"),
        "time",
    ),
    **dict.fromkeys(("hour", "hours"), "time"),
    **dict.fromkeys(("MB", "MiB", "GB", "GiB", "KiB", "kB"), "size"),
    **dict.fromkeys(("it/s", "maps/s", "images/s", "img/s", "fps"), "rate"),
}


def _kind_fits(n: Number, path: Path_) -> bool:
    kind = _UNIT_KIND.get(n.unit)
    if kind is None:
        return True
    return re.search(_KIND[kind], ".".join(map(str, path)).lower()) is not None


def _direct(n: Number, leaves: tuple[tuple[Path_, float], ...]) -> bool:
    scales = _SCALES.get(n.unit, (1.0,))
    signed = -n.value if n.sign == "-" else n.value
    for path, v in leaves:
        if not _kind_fits(n, path):
            continue
        for k in scales:
            c = v * k
            if _equal_at(c, n) and (
                n.sign == "" or math.copysign(1, c) == math.copysign(1, signed)
            ):
                return True
    return False


def _long_lists(value: object, path: Path_ = ()) -> Iterator[Path_]:
    """Paths of the lists longer than `_MAX_VARIANTS` (per-item tables: pairs, fits, views)."""
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _long_lists(v, (*path, str(k)))
    elif isinstance(value, list):
        if len(value) > _MAX_VARIANTS:
            yield path
        for k, v in enumerate(value):
            yield from _long_lists(v, (*path, k))


@functools.cache
def _siblings(source: str) -> tuple[tuple[str, float, float], ...]:
    """Pairs (metric key, a, b) of one file's leaves that are one metric of two variants.

    Either the same path except for one component before the last (`summary.full.psnr` vs
    `summary.unrelit.psnr`, `rows[2].psnr` vs `rows[0].psnr` in a list of at most `_MAX_ROWS`), or the same path except that one last
    key is the other's baseline (`input_object_psnr` vs `object_psnr`: one ends with `_` + the
    other). Leaves inside a list of more than `_MAX_VARIANTS` entries (a per-item table, where some
    difference would match almost anything) are left out, and so are groups larger than that.
    """
    long_lists = set(_long_lists(json.loads((ROOT / source).read_text())))
    groups: dict[tuple[int, Path_], list[float]] = {}
    index_groups: set[tuple[int, Path_]] = set()
    for path, v in source_leaves(source):
        if any(path[:i] in long_lists for i, part in enumerate(path) if isinstance(part, int)):
            continue
        indices = [i for i, part in enumerate(path) if isinstance(part, int)]
        for i in range(len(path) - 1):
            # inside a list only the row varies (per-row variants would pair up per-item values)
            if indices and i not in indices:
                continue
            groups.setdefault((i, (*path[:i], "*", *path[i + 1 :])), []).append(v)
            if isinstance(path[i], int):
                index_groups.add((i, (*path[:i], "*", *path[i + 1 :])))
        last = path[-1]
        if isinstance(last, str):
            # a baseline's key: input_X, unrelit_input_X, baseline_X -> X
            for cut in range(len(last)):
                if last[cut] == "_" and cut + 1 < len(last):
                    groups.setdefault((-1, (*path[:-1], last[cut + 1 :])), []).append(v)
            groups.setdefault((-1, path), []).append(v)
    pairs = []
    for key, members in groups.items():
        metric = str(key[1][-1]).lower()
        # rows of a list are variants only in a short table (the model card's four rows)
        limit = _MAX_ROWS if key in index_groups else _MAX_VARIANTS
        if 1 < len(members) <= limit:
            pairs += [
                (metric, a, b)
                for i, a in enumerate(members)
                for j, b in enumerate(members)
                if i != j
            ]
    return tuple(pairs)


_MAX_VARIANTS = 16
_MAX_ROWS = 8


_RATE = re.compile(
    r"second|_s$|^s_|_s_|ms|time|per_s|maps|images|speed|throughput|mib|mb|bytes|param"
)


def _derived(n: Number, source: str) -> bool:
    # a difference in dB is one of PSNRs (the key names psnr or db), not of seconds or SSIM
    def fits(metric: str) -> bool:
        return n.unit != "dB" or "psnr" in metric or "db" in metric

    if n.sign or n.unit == "dB":  # a signed difference, or a gap in dB ("0.43 dB below")
        target = -n.value if n.sign == "-" else n.value
        for metric, a, b in _siblings(source):
            d = a - b
            same_sign = not n.sign or math.copysign(1, d) == math.copysign(1, target)
            if fits(metric) and same_sign and _equal_at(d, n):
                return True
        return False
    if n.unit in ("x", "×"):
        # a ratio compares costs or rates (seconds, ms, maps/s, MiB), not two PSNRs
        return any(
            b != 0 and _RATE.search(metric) and _equal_at(a / b, n)
            for metric, a, b in _siblings(source)
        )
    return False


def explain(n: Number, sources: tuple[str, ...]) -> list[str]:
    """Where a number matched (`--explain`): the leaf paths, or the derived pair's values."""
    found = []
    for source in sources:
        for path, v in source_leaves(source):
            if _direct(n, ((path, v),)):
                found.append(f"{source}:{'.'.join(map(str, path))} = {v}")
        if not found and _derived(n, source):
            found.append(f"{source}: derived (difference or ratio of sibling values)")
    return found


def _matches(n: Number, sources: tuple[str, ...]) -> bool:
    for source in sources:
        leaves = source_leaves(source)
        if _direct(n, leaves) or _derived(n, source):
            return True
    return False


# ---------------------------------------------------------------------------------------------
# Pins
# ---------------------------------------------------------------------------------------------
def _leaf(source: str, keys: str) -> float:
    """The numeric leaf at `keys` (dot-separated; list indexes as numbers) of one JSON file.

    A key that itself holds dots is found too (the longest run of parts that is a key wins).
    Raises ValueError naming what is missing.
    """
    path = ROOT / source
    if not source.endswith(".json") or not path.is_file():
        raise ValueError(f"{source} is not a JSON file")
    value: object = json.loads(path.read_text())
    parts = keys.split(".")
    while parts:
        if isinstance(value, list) and re.fullmatch(r"\d+", parts[0]):
            index = int(parts.pop(0))
            if index >= len(value):
                raise ValueError(f"{source}#{keys}: index {index} past the list's end")
            value = value[index]
            continue
        if isinstance(value, dict):
            for take in range(len(parts), 0, -1):
                key = ".".join(parts[:take])
                if key in value:
                    value, parts = value[key], parts[take:]
                    break
            else:
                raise ValueError(f"{source}#{keys}: no key {parts[0]!r}")
            continue
        raise ValueError(f"{source}#{keys}: {parts[0]!r} under a {type(value).__name__}")
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{source}#{keys} is not a number")
    return float(value)


def pin_value(pin: Pin) -> float:
    """The value a pin names (a leaf, or the difference or ratio of two). Raises ValueError."""
    m = _PIN_EXPR.match(pin.right)
    if not m:
        raise ValueError(f"pin {pin.left!r}: {pin.right!r} is not FILE#PATH [ - or / [FILE]#PATH]")
    source, keys = m.group("a").split("#", 1)
    a = _leaf(source, keys)
    if not m.group("op"):
        return a
    other, other_keys = m.group("b").split("#", 1)
    b = _leaf(other or source, other_keys)
    if m.group("op") == "-":
        return a - b
    if b == 0:
        raise ValueError(f"pin {pin.left!r}: {pin.right} divides by zero")
    return a / b


def pinned_by(n: "Number", pin: Pin) -> bool:
    """Whether page number `n` is the one `pin` names (same digits and sign; the unit if given)."""
    found = list(measured_numbers(Line(0, pin.left, ())))
    if len(found) != 1:
        return False
    p = found[0]
    same_unit = p.unit == n.unit or not p.unit
    return (p.value, p.decimals, p.sign) == (n.value, n.decimals, n.sign) and same_unit


def pin_agrees(n: "Number", value: float) -> bool:
    """`n` shows `value` at its precision (with its unit's scaling and its sign)."""
    signed = -n.value if n.sign == "-" else n.value
    for k in _SCALES.get(n.unit, (1.0,)):
        c = value * k
        if _equal_at(c, n) and math.copysign(1, c) == math.copysign(1, signed or c):
            return True
    return False


# ---------------------------------------------------------------------------------------------
# Generated blocks
# ---------------------------------------------------------------------------------------------
def _card_module() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "gaffer_tiny_card", ROOT / "benchmarks" / "gaffer_tiny_card.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def check_generated(path: Path, blocks: list[tuple[int, str, str]]) -> list[str]:
    """Generated blocks must equal what their generator makes from the result files now."""
    if not blocks:
        return []
    card = _card_module()
    text = path.read_text()
    rel = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
    failures = []
    generated = card.tables()
    in_page = card.card_tables(text)
    for line, kind, name in blocks:
        if kind == "table":
            if name not in generated:
                failures.append(
                    f"{rel}:{line}: table {name!r} has no generator in gaffer_tiny_card.py"
                )
            elif in_page.get(name) != generated[name]:
                failures.append(
                    f"{rel}:{line}: table {name!r} differs from gaffer_tiny_card.py's (run --write)"
                )
        elif name == "gaffer-tiny-headline":
            if card.readme_headline(text) != card.headline():
                failures.append(f"{rel}:{line}: the headline differs from gaffer_tiny_card.py's")
        else:
            failures.append(f"{rel}:{line}: generated block {name!r} has no known generator")
    return failures


# ---------------------------------------------------------------------------------------------
def check_page(path: Path) -> list[str]:
    """Every failure of one page, as `file:line: number: why` (sources resolve against the repository)."""
    rel = str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)
    page = read_page(path)
    allowed = NOT_MEASURED.get(rel, {})
    used: set[str] = set()
    failures = check_generated(path, page.generated)
    values: dict[Pin, float] = {}
    for pin in page.pins:
        try:
            values[pin] = pin_value(pin)
        except ValueError as e:
            failures.append(f"{rel}:{pin.line}: {pin.left}: {e}")
    pins_used: set[Pin] = set()
    for line in page.lines:
        for source in line.sources:
            if not (ROOT / source).is_file() or not source.endswith(".json"):
                failures.append(f"{rel}:{line.number}: declared source {source} is not a JSON file")
        for n in measured_numbers(line):
            pins = [p for p in page.pins if p.paragraph == line.paragraph and pinned_by(n, p)]
            if pins:
                pins_used.update(pins)
                for p in pins:
                    if p in values and not pin_agrees(n, values[p]):
                        failures.append(
                            f"{rel}:{line.number}: {n.text}: pinned to {p.right} = "
                            f"{values[p]:.6g}, which it does not show"
                        )
                continue
            key = n.text if n.text in allowed else None
            if key is not None:
                used.add(key)
                continue
            if not line.sources:
                failures.append(f"{rel}:{line.number}: {n.text}: no numbers-from source declared")
            elif not _matches(n, tuple(s for s in line.sources if (ROOT / s).is_file())):
                failures.append(
                    f"{rel}:{line.number}: {n.text}: matches no value of {' '.join(line.sources)}"
                )
    for pin in page.pins:
        if pin not in pins_used:
            failures.append(
                f"{rel}:{pin.line}: {pin.left}: pinned, but not a measured number of its paragraph"
            )
    # an entry whose number left the page is stale: the list stays as short as the text needs
    for stale in sorted(set(allowed) - used):
        failures.append(f"{rel}:0: {stale}: listed in NOT_MEASURED, not on the page (or pinned)")
    return sorted(dict.fromkeys(failures), key=_failure_line)


def _failure_line(failure: str) -> tuple[str, int]:
    m = re.match(r"(.*?):(\d+): ", failure)
    return (m.group(1), int(m.group(2))) if m else (failure, 0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("files", nargs="*", type=Path, help="pages to check (default: all)")
    parser.add_argument(
        "--explain", metavar="LINE", type=int, help="show where LINE's numbers match"
    )
    args = parser.parse_args(argv)
    if args.explain is not None:
        for path in args.files:
            page = read_page(path.resolve())
            for line in page.lines:
                if line.number == args.explain:
                    for n in measured_numbers(line):
                        pins = [
                            f"pinned: {p.right}"
                            for p in page.pins
                            if p.paragraph == line.paragraph and pinned_by(n, p)
                        ]
                        print(n.text, "->", pins or explain(n, line.sources) or "no match")
        return 0
    targets = [p.resolve() for p in args.files] or pages()
    failures = [f for p in targets for f in check_page(p)]
    for f in failures:
        print(f)
    print(f"{len(failures)} number(s) without a matching source in {len(targets)} page(s)")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
