"""The tables of gaffer-tiny's model card, generated from the committed per-pair evaluation files.

`bench_reshade.py --update-baseline` writes one file per scored row to
`results/reshade/<split>-<label>.json` (every pair's scores, the unrelit input's, the sha256 of the
weights, the split manifest's sha256 and each pair's target map). This script turns them into the
markdown tables that MODEL_CARD.md carries, so every number there has a source file:

    python benchmarks/gaffer_tiny_card.py            # print the tables
    python benchmarks/gaffer_tiny_card.py --check    # exit 1 when the card's tables differ
    python benchmarks/gaffer_tiny_card.py --write    # rewrite the card's tables (and README's headline)

Each table is delimited in the card by `<!-- table: NAME -->` ... `<!-- /table -->`.
"""

import argparse
import json
import math
import re
import sys
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

RESULTS = Path(__file__).parent / "results" / "reshade"
CARD = (
    Path(__file__).parents[1]
    / "packages/gaffer-diffusion/src/gaffer_diffusion/weights/gaffer-tiny/MODEL_CARD.md"
)

VALIDATION_SPLIT = "render_val05"
TEST_SPLIT = "render_test08"
SHIPPED_LABEL = "gaffer-tiny-0.7"
# earlier releases' own test splits (0.6's, 0.5.1's and 0.5's), each scored once for its release;
# kept in the card's history, table name -> split
EARLIER_TEST_SPLITS = {
    "test07": "render_test07",
    "test06": "render_test06",
    "test05": "render_test05",
}


@dataclass(frozen=True)
class Scored:
    """One row's per-pair file, read."""

    label: str
    doc: dict[str, Any]

    @property
    def settings(self) -> dict[str, Any]:
        return self.doc["settings"]


WEIGHTS = CARD.parents[1]


def _sha256(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()


def _release(row: Scored) -> str:
    """The row's release; a checkpoint scored before a release whose weights (UNet, and the normal
    estimator it used) are the shipped ones says so, so the shipped model's validation row reads as
    the shipped model's."""
    release = str(row.settings.get("release", "-"))
    if release != "unreleased checkpoint":
        return release
    unet = _sha256(WEIGHTS / "gaffer-tiny" / "unet" / "diffusion_pytorch_model.safetensors")
    estimator = _sha256(WEIGHTS / "gaffer-normals" / "unet" / "diffusion_pytorch_model.safetensors")
    same_estimator = row.settings.get("hint_geometry") != "estimated" or (
        row.settings.get("normal_estimator_sha256") == estimator
    )
    if row.settings.get("unet_sha256") == unet and same_estimator:
        shipped = json.loads((WEIGHTS / "gaffer-tiny" / "gaffer_model.json").read_text())["release"]
        return f"{shipped['name']} {shipped['version']}'s weights, scored before release"
    return release


def _read(split: str) -> list[Scored]:
    rows = []
    for path in sorted(RESULTS.glob(f"{split}-*.json")):
        rows.append(Scored(path.stem[len(split) + 1 :], json.loads(path.read_text())))
    return rows


def _mean_psnr(items: list[dict[str, Any]], key: str) -> float:
    # the reports' own mean: PSNR of the mean MSE would differ; this is the mean of per-pair PSNRs,
    # as `MetricsReport` computes it (gaffer_diffusion.metrics)
    return sum(float(i[key]["psnr"]) for i in items) / len(items)


def _closer(items: list[dict[str, Any]], base: list[dict[str, Any]]) -> float:
    wins = sum(
        1
        for a, b in zip(items, base, strict=True)
        if float(a["object_raw"]["psnr"]) > float(b["object_raw"]["psnr"])
    )
    return wins / len(items)


def _fmt_lpips(value: Any) -> str:
    return "n/a" if value is None or not math.isfinite(float(value)) else f"{float(value):.4f}"


def _scored_indices(row: Scored) -> list[int]:
    """Pairs with something to relight: a pair whose unrelit input equals its target over the object
    (an infinite input PSNR, written as null) measures no lighting change and is left out of every
    mean, for every row alike (render_test05: the 20 pairs of one pybullet shape that renders
    saturated white under every map)."""
    base = row.doc["baseline_unrelit_input"]["items"]
    return [i for i, b in enumerate(base) if b["object_raw"]["psnr"] is not None]


def _mean_of(items: list[dict[str, Any]], key: str, field: str = "psnr") -> float | None:
    values = [i[key][field] for i in items]
    if any(v is None for v in values):
        return None
    return sum(float(v) for v in values) / len(values)


def row_means(doc: dict[str, Any]) -> dict[str, Any]:
    """One per-pair file's means over the pairs with something to relight (`_scored_indices`): the
    numbers `bench_reshade.py` charts, so the chart and the card agree."""
    row = Scored("", doc)
    keep = _scored_indices(row)
    items = [doc["metrics"]["items"][i] for i in keep]
    base = [doc["baseline_unrelit_input"]["items"][i] for i in keep]
    return {
        "pairs": len(items),
        "pairs_left_out_unchanged": len(doc["metrics"]["items"]) - len(keep),
        "object_psnr_raw": _mean_psnr(items, "object_raw"),
        "object_psnr_aligned": _mean_psnr(items, "object_aligned"),
        "object_stlpips": _mean_of(items, "object_raw", "perceptual"),
        "closer_than_input": _closer(items, base),
        "full_psnr": _mean_psnr(items, "raw"),
        "input_object_psnr_raw": _mean_psnr(base, "object_raw"),
        "input_object_psnr_aligned": _mean_psnr(base, "object_aligned"),
        "input_object_stlpips": _mean_of(base, "object_raw", "perceptual"),
    }


def summary_table(split: str) -> str:
    """Every scored row of `split` beside the unrelit input (object mask, display space)."""
    rows = _read(split)
    if not rows:
        raise SystemExit(f"no results/reshade/{split}-*.json: run bench_reshade.py first")
    lines = [
        "| prediction | hint geometry | release | object PSNR raw | object PSNR aligned | "
        "object ST-LPIPS (crop) | closer than input | full-frame PSNR | pairs (left out) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    keep = _scored_indices(rows[0])
    for r in rows:
        if _scored_indices(r) != keep:
            raise SystemExit(f"{split}-{r.label}: not the same pairs as {rows[0].label}")
        items = [r.doc["metrics"]["items"][i] for i in keep]
        base = [r.doc["baseline_unrelit_input"]["items"][i] for i in keep]
        left = len(r.doc["metrics"]["items"]) - len(keep)
        lines.append(
            f"| {r.label} | {r.settings['hint_geometry']} | {_release(r)} | "
            f"{_mean_psnr(items, 'object_raw'):.2f} | {_mean_psnr(items, 'object_aligned'):.2f} | "
            f"{_fmt_lpips(_mean_of(items, 'object_raw', 'perceptual'))} | "
            f"{100 * _closer(items, base):.0f}% | {_mean_psnr(items, 'raw'):.2f} | "
            f"{len(items)} ({left}) |"
        )
    base = [rows[0].doc["baseline_unrelit_input"]["items"][i] for i in keep]
    left = len(rows[0].doc["metrics"]["items"]) - len(keep)
    lines.append(
        f"| unrelit input | - | - | {_mean_psnr(base, 'object_raw'):.2f} | "
        f"{_mean_psnr(base, 'object_aligned'):.2f} | "
        f"{_fmt_lpips(_mean_of(base, 'object_raw', 'perceptual'))} | - | "
        f"{_mean_psnr(base, 'raw'):.2f} | {len(base)} ({left}) |"
    )
    return "\n".join(lines)


def by_hdri_table(split: str, label: str) -> str:
    """One row's object-mask scores by target map, beside the unrelit input's."""
    row = next((r for r in _read(split) if r.label == label), None)
    if row is None:
        raise SystemExit(f"no results/reshade/{split}-{label}.json")
    targets = row.doc["pair_target_envmap"]
    groups: dict[str, list[int]] = defaultdict(list)
    items = row.doc["metrics"]["items"]
    base = row.doc["baseline_unrelit_input"]["items"]
    for i in _scored_indices(row):
        groups[str(targets[items[i]["name"]])].append(i)
    lines = [
        "| target map | pairs | PSNR relit | PSNR input | aligned relit | aligned input | closer |",
        "|---|---|---|---|---|---|---|",
    ]
    for name in sorted(groups):
        mine = [items[i] for i in groups[name]]
        theirs = [base[i] for i in groups[name]]
        lines.append(
            f"| {name} | {len(mine)} | {_mean_psnr(mine, 'object_raw'):.2f} | "
            f"{_mean_psnr(theirs, 'object_raw'):.2f} | {_mean_psnr(mine, 'object_aligned'):.2f} | "
            f"{_mean_psnr(theirs, 'object_aligned'):.2f} | {100 * _closer(mine, theirs):.0f}% |"
        )
    return "\n".join(lines)


README = Path(__file__).parents[1] / "README.md"


def headline() -> str:
    """The README's sentence of gaffer-tiny's test scores, from the shipped row's per-pair file."""
    row = next((r for r in _read(TEST_SPLIT) if r.label == SHIPPED_LABEL), None)
    if row is None:
        raise SystemExit(f"no results/reshade/{TEST_SPLIT}-{SHIPPED_LABEL}.json")
    m = row_means(row.doc)
    base_full = _mean_psnr(
        [row.doc["baseline_unrelit_input"]["items"][i] for i in _scored_indices(row)], "raw"
    )
    raw, raw_in = m["object_psnr_raw"], m["input_object_psnr_raw"]
    al, al_in = m["object_psnr_aligned"], m["input_object_psnr_aligned"]
    return (
        f"On a test split of unseen objects under unseen HDRIs ({m['pairs']} pairs), over the object "
        f"mask, {row.settings['release']} scores {raw:.2f} dB PSNR vs {raw_in:.2f} dB for the unrelit "
        f"input ({raw - raw_in:+.2f} dB), {al:.2f} vs {al_in:.2f} dB channel-aligned "
        f"({al - al_in:+.2f} dB), ST-LPIPS {m['object_stlpips']:.4f} vs "
        f"{m['input_object_stlpips']:.4f} on the object crop, and is closer to the truth than the "
        f"input on {100 * m['closer_than_input']:.0f}% of pairs (full frame: {m['full_psnr']:.2f} vs "
        f"{base_full:.2f} dB)."
    )


HEADLINE = re.compile(
    r"(<!-- generated: gaffer-tiny-headline -->\n)(.*?)(\n<!-- /generated -->)", re.S
)


def readme_headline(text: str) -> str | None:
    """The README's generated headline block (joined into one line), or None."""
    found = HEADLINE.search(text)
    return None if found is None else " ".join(found.group(2).split())


def tables() -> dict[str, str]:
    return {
        "validation": summary_table(VALIDATION_SPLIT),
        "test": summary_table(TEST_SPLIT),
        "test-by-hdri": by_hdri_table(TEST_SPLIT, SHIPPED_LABEL),
        "test-by-hdri-06": by_hdri_table(TEST_SPLIT, "gaffer-tiny-0.6"),
        # 0.6 by map on its own test split: where it gained least is what 0.7's data aimed at
        "test07-by-hdri": by_hdri_table("render_test07", "gaffer-tiny-0.6"),
        **{name: summary_table(split) for name, split in EARLIER_TEST_SPLITS.items()},
    }


def _wrap(text: str, width: int = 104) -> str:
    import textwrap

    return "\n".join(textwrap.wrap(text, width, break_on_hyphens=False))


def card_tables(text: str) -> dict[str, str]:
    pattern = re.compile(r"<!-- table: ([\w-]+) -->\n(.*?)\n<!-- /table -->", re.S)
    return {m.group(1): m.group(2).strip() for m in pattern.finditer(text)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--check", action="store_true", help="compare with MODEL_CARD.md")
    mode.add_argument("--write", action="store_true", help="rewrite MODEL_CARD.md's tables")
    args = parser.parse_args(argv)
    generated = tables()
    if args.write:
        text = CARD.read_text()
        missing = set(generated) - set(card_tables(text))
        if missing:
            raise SystemExit(
                f"MODEL_CARD.md has no <!-- table: NAME --> block for {sorted(missing)}"
            )
        for name, table in generated.items():
            text = re.sub(
                rf"(<!-- table: {re.escape(name)} -->\n).*?(\n<!-- /table -->)",
                lambda m, t=table: m.group(1) + t + m.group(2),
                text,
                flags=re.S,
            )
        CARD.write_text(text)
        readme = README.read_text()
        if readme_headline(readme) is None:
            raise SystemExit("README.md has no <!-- generated: gaffer-tiny-headline --> block")
        README.write_text(
            HEADLINE.sub(lambda m: m.group(1) + _wrap(headline()) + m.group(3), readme)
        )
        print(f"rewrote {len(generated)} tables in {CARD} and the headline in {README}")
        return 0
    if not args.check:
        for name, table in generated.items():
            print(f"<!-- table: {name} -->\n{table}\n<!-- /table -->\n")
        return 0
    in_card = card_tables(CARD.read_text())
    bad = [name for name, table in generated.items() if in_card.get(name) != table]
    for name in bad:
        print(f"MODEL_CARD.md table {name!r} differs from results/reshade (regenerate it)")
    if readme_headline(README.read_text()) != headline():
        print("README.md's gaffer-tiny headline differs from results/reshade (regenerate it)")
        bad.append("README headline")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
