"""gaffer-tiny's model card and the README headline carry numbers generated from committed result files.

`benchmarks/gaffer_tiny_card.py` rebuilds each table of MODEL_CARD.md from the per-pair evaluation
files in `benchmarks/results/reshade/`; a number edited by hand in the card, or a result file replaced
without regenerating the card, fails here.
"""

import importlib.util
import json
from pathlib import Path

ROOT = Path(__file__).parents[2]
SCRIPT = ROOT / "benchmarks" / "gaffer_tiny_card.py"
SHIPPED = ROOT / "packages/gaffer-diffusion/src/gaffer_diffusion/weights/gaffer-tiny"


def _card_module():
    spec = importlib.util.spec_from_file_location("gaffer_tiny_card", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_model_card_tables_match_the_result_files() -> None:
    card = _card_module()
    generated = card.tables()
    in_card = card.card_tables(card.CARD.read_text())
    assert set(generated) <= set(in_card), (
        f"tables missing from the card: {set(generated) - set(in_card)}"
    )
    for name, table in generated.items():
        assert in_card[name] == table, f"MODEL_CARD.md table {name!r} differs from its result files"


def test_the_shipped_rows_measured_the_shipped_weights() -> None:
    """The test rows labelled as the shipped release name its version and its weights' sha256."""
    import hashlib

    card = _card_module()
    weights = SHIPPED / "unet" / "diffusion_pytorch_model.safetensors"
    sha = hashlib.sha256(weights.read_bytes()).hexdigest()
    release = json.loads((SHIPPED / "gaffer_model.json").read_text())["release"]
    label = f"{release['name']} {release['version']}"
    rows = [r for r in card._read(card.TEST_SPLIT) if r.label.startswith(card.SHIPPED_LABEL)]
    assert rows, "no test rows of the shipped model"
    estimator = ROOT / (
        "packages/gaffer-diffusion/src/gaffer_diffusion/weights/gaffer-normals/unet/"
        "diffusion_pytorch_model.safetensors"
    )
    estimator_sha = hashlib.sha256(estimator.read_bytes()).hexdigest()
    for row in rows:
        assert row.settings["release"] == label
        assert row.settings["unet_sha256"] == sha
        if row.settings["hint_geometry"] == "estimated":
            assert row.settings["normal_estimator_sha256"] == estimator_sha


def test_readme_headline_matches_the_result_files() -> None:
    """The README's gaffer-tiny scores are the generated sentence, not hand-typed numbers."""
    card = _card_module()
    in_readme = card.readme_headline(card.README.read_text())
    assert in_readme is not None, (
        "README.md lost its <!-- generated: gaffer-tiny-headline --> block"
    )
    assert in_readme == card.headline(), "README.md's headline differs: gaffer_tiny_card.py --write"


def test_readme_module_map_names_files_that_exist() -> None:
    """Each package's "where its work starts" entries in README.md point at real modules: a renamed or moved module fails here instead of leaving a dead pointer."""
    import re

    text = (ROOT / "README.md").read_text()
    rows = [ln for ln in text.splitlines() if ln.startswith("| `packages/gaffer-")]
    assert len(rows) == 4, "README.md's package table should have one row per package"
    for row in rows:
        pkg = re.match(r"\| `packages/(gaffer-\w+)`", row)
        assert pkg is not None
        src = ROOT / "packages" / pkg.group(1) / "src" / pkg.group(1).replace("-", "_")
        start = row.rsplit("|", 2)[1]
        named = re.findall(r"`([\w/]+\.py)`", start)
        assert named, f"{pkg.group(1)}: no module named in 'where its work starts'"
        for path in named:
            rel = path.split("/", 1)[1] if path.startswith(src.name + "/") else path
            assert (src / rel).is_file(), f"README.md names {path}, not in {src}"


def test_the_shipped_weights_validation_row_says_it_is_the_shipped_model() -> None:
    """A checkpoint scored on validation before release whose UNet and normal estimator are the
    shipped ones is the shipped model's validation: its row names the release, not "unreleased"."""
    import hashlib

    card = _card_module()
    unet = hashlib.sha256(
        (SHIPPED / "unet" / "diffusion_pytorch_model.safetensors").read_bytes()
    ).hexdigest()
    release = json.loads((SHIPPED / "gaffer_model.json").read_text())["release"]
    shipped_rows = [
        r for r in card._read(card.VALIDATION_SPLIT) if r.settings.get("unet_sha256") == unet
    ]
    assert shipped_rows, "no validation file of the shipped weights"
    table = card.card_tables(card.CARD.read_text())["validation"]
    named = [
        r for r in shipped_rows if f"{release['name']} {release['version']}" in card._release(r)
    ]
    assert named, "the shipped weights' validation row does not name the release"
    for r in named:
        row = next(line for line in table.splitlines() if line.startswith(f"| {r.label} |"))
        # scored before release: "<release>'s weights, scored before release"; after it (e.g. an
        # oracle row of the shipped model): the release itself
        before = r.settings.get("release") == "unreleased checkpoint"
        tag = f"{release['name']} {release['version']}" + ("'s weights" if before else " |")
        assert tag in row
