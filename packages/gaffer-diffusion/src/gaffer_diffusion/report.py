"""The demo's HTML report: one self-contained page (inline CSS, images linked by relative path).

`render_html` turns a `ReportContent` into HTML; nothing here reads or writes files, so the page is
easy to test. Every string from the data is HTML-escaped.
"""

import html
from dataclasses import dataclass

from gaffer_diffusion.metrics import ImageScores

_CSS = """
body { font: 14px/1.4 system-ui, sans-serif; margin: 2em; color: #222; }
h1 { font-size: 1.4em; } h2 { font-size: 1.15em; margin-top: 2em; }
table { border-collapse: collapse; margin: 0.5em 0; }
th, td { border: 1px solid #ccc; padding: 4px 8px; text-align: left; vertical-align: middle; }
th { background: #f3f3f3; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
img.px { width: 128px; height: 128px; image-rendering: pixelated; display: block; }
img.world { width: 192px; height: 96px; display: block; }
table.scores td, table.scores th { font-size: 12px; padding: 2px 6px; }
.note { color: #555; font-size: 12px; }
"""


@dataclass(frozen=True, kw_only=True)
class LightingRow:
    """One lighting of the report: its pictures (relative paths) and, with ground truth, its scores.

    Attributes:
        key: file stem, e.g. "003_sunset".
        label: human-readable lighting (map name and augmentation).
        world: the world map, tone-mapped.
        ldr: the camera-frame LDR encoding E_L.
        hdr: the camera-frame HDR encoding E_H.
        input: the model's input image.
        relit: the relit image.
        ground_truth: the ground-truth render, or None (no render under this lighting).
        scores: (variant label, scores) pairs; empty without ground truth.
    """

    key: str
    label: str
    world: str
    ldr: str
    hdr: str
    input: str
    relit: str
    ground_truth: str | None
    scores: tuple[tuple[str, ImageScores], ...]


@dataclass(frozen=True, kw_only=True)
class ReportContent:
    """Everything the report shows.

    Attributes:
        title: page title.
        settings: (name, value) pairs: model, steps, device, ...
        timings: (stage, duration text) pairs.
        perceptual_label: column header of the perceptual metric (e.g. "stlpips-alex").
        perceptual_note: what the perceptual metric is, or why it is missing.
        means: (variant label, mean scores) pairs: model and baselines.
        rows: one per lighting.
        turntable_gif: relative path of the turntable GIF, or None.
        turntable_label: what spins in the turntable.
        created_utc: ISO time stamp.
        summary: the headline (object-mask scores first), shown above the tables.
    """

    title: str
    settings: tuple[tuple[str, str], ...]
    timings: tuple[tuple[str, str], ...]
    perceptual_label: str
    perceptual_note: str | None
    means: tuple[tuple[str, ImageScores], ...]
    rows: tuple[LightingRow, ...]
    turntable_gif: str | None
    turntable_label: str | None
    created_utc: str
    summary: str = ""


def _e(text: object) -> str:
    return html.escape(str(text), quote=True)


def _img(src: str | None, alt: str, cls: str = "px") -> str:
    if src is None:
        return '<span class="note">no render</span>'
    return f'<a href="{_e(src)}"><img class="{cls}" src="{_e(src)}" alt="{_e(alt)}"></a>'


def _num(value: float | None, digits: int) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def _scores_table(rows: tuple[tuple[str, ImageScores], ...], perceptual: str, cls: str) -> str:
    out = [f'<table class="{cls}"><tr><th>variant</th><th>PSNR (dB) &uarr;</th>']
    out.append(f"<th>SSIM &uarr;</th><th>{_e(perceptual)} &darr;</th></tr>")
    for label, s in rows:
        out.append(
            f'<tr><td>{_e(label)}</td><td class="num">{_num(s.psnr, 2)}</td>'
            f'<td class="num">{_num(s.ssim, 4)}</td><td class="num">{_num(s.perceptual, 4)}</td></tr>'
        )
    out.append("</table>")
    return "".join(out)


def _kv_table(pairs: tuple[tuple[str, str], ...]) -> str:
    body = "".join(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>" for k, v in pairs)
    return f"<table>{body}</table>"


def image_links(page: str) -> list[str]:
    """Every `src`/`href` target in `page` (for checking that a written report is complete).

    Example:
        >>> image_links('<a href="a.png"><img src="a.png"></a>')
        ['a.png', 'a.png']
    """
    import re

    return [html.unescape(m) for m in re.findall(r'(?:src|href)="([^"]*)"', page)]


def render_html(content: ReportContent) -> str:
    """The report as one HTML document (UTF-8, inline CSS, relative image links)."""
    c = content
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        f"<title>{_e(c.title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{_e(c.title)}</h1>",
        f'<p class="note">Written {_e(c.created_utc)} by <code>gaffer-diffusion demo</code>. '
        "Images are shown enlarged without smoothing; click one for the file. The model is "
        "conditioned on the input image and on the target lighting's two camera-frame encodings "
        "(E_L: LDR, E_H: log-normalised HDR; Neural Gaffer &sect;3.2).</p>",
        f"<p><b>{_e(c.summary)}</b></p>" if c.summary else "",
        "<h2>Mean scores over the lightings with ground truth</h2>",
        "<p>Object-mask rows first (PSNR of the MSE over the object's alpha, mask-weighted SSIM, "
        "the perceptual metric on the object's box); full-frame rows (the authors' protocol, "
        "dominated by the white background) after them.</p>",
        _scores_table(c.means, c.perceptual_label, "means"),
    ]
    if c.perceptual_note:
        parts.append(f'<p class="note">{_e(c.perceptual_note)}</p>')
    parts.append(
        '<p class="note">Channel alignment rescales each colour channel so that its mean matches '
        "the ground truth's (NeRFactor / InvRender), over the whole image or the object mask. A "
        "relighting model should beat both baselines: the unrelit input, and the input "
        "channel-aligned to the target (a global colour change, no new shading).</p>"
    )
    if c.turntable_gif is not None:
        parts += [
            "<h2>Turntable</h2>",
            f"<p>{_e(c.turntable_label)} (left: E_L, right: relit).</p>",
            f'<img src="{_e(c.turntable_gif)}" alt="turntable" style="image-rendering: pixelated">',
        ]
    parts += [
        "<h2>Per lighting</h2>",
        "<table><tr><th>lighting</th><th>world map</th><th>E_L</th><th>E_H</th><th>input</th>",
        "<th>relit</th><th>ground truth</th><th>scores</th></tr>",
    ]
    for r in c.rows:
        scores = (
            _scores_table(r.scores, c.perceptual_label, "scores")
            if r.scores
            else '<span class="note">no ground truth</span>'
        )
        parts.append(
            f"<tr><td><b>{_e(r.key)}</b><br>{_e(r.label)}</td>"
            f"<td>{_img(r.world, 'world map', 'world')}</td><td>{_img(r.ldr, 'E_L')}</td>"
            f"<td>{_img(r.hdr, 'E_H')}</td><td>{_img(r.input, 'input')}</td>"
            f"<td>{_img(r.relit, 'relit')}</td><td>{_img(r.ground_truth, 'ground truth')}</td>"
            f"<td>{scores}</td></tr>"
        )
    parts += [
        "</table>",
        "<h2>Timings</h2>",
        _kv_table(c.timings),
        "<h2>Settings</h2>",
        _kv_table(c.settings),
        '<p class="note">All numbers are also in <a href="metrics.json">metrics.json</a>; '
        'every picture on one sheet: <a href="overview.png">overview.png</a>.</p>',
        "</body></html>",
        "",
    ]
    return "\n".join(parts)
