"""Give every committed result file a `provenance` block: what it measured and where.

New runs record this themselves (`_common.machine`, `_common.model_provenance`,
`_common.data_provenance`). Files written before that lack some of it; this script adds what git can
still tell, and says where it comes from, without touching the measured numbers:

- `code_commit`: the file's own `machine.git_commit` when it has one, else the commit that added the
  file to git (the code measured is at or before it: `code_commit_is` says which);
- `machine`: the recorded CPU model, or "not recorded";
- `model`: for results of a trained gaffer-tiny that did not name its weights, the release and the
  sha256 of every weights file of `weights/gaffer-tiny/` at the recorded commit, read from git, and
  `shipped` (true only when those hashes equal the shipped folder's now); for a result of a random or
  no model, what it used;
- `data`: for results of a dataset kept in git (`DATA_AT_COMMIT`: the shipped example), the sha256 of
  its manifest at the recorded commit (the manifest lists every object, view and lighting).

    python benchmarks/backfill_provenance.py           # add or refresh the blocks
    python benchmarks/backfill_provenance.py results/x.json   # only these files
    python benchmarks/backfill_provenance.py --check   # exit 1 when a file fails to name them

The test `tests/benchmarks/test_result_provenance.py` requires every file to name its commit, machine
and (where one was used) its model's weights.
"""

import argparse
import hashlib
import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
RESULTS = REPO / "benchmarks" / "results"
WEIGHTS = "packages/gaffer-diffusion/src/gaffer_diffusion/weights/gaffer-tiny"
BY = "benchmarks/backfill_provenance.py (issue 34)"

# Results measured with a trained gaffer-tiny whose files name only "gaffer-tiny": their weights are
# those of the recorded commit (bench_nerf_real.py and the validation sweeps load the shipped folder).
TINY_AT_COMMIT = (
    "nerf_real.json",
    "nerf_noise_val.json",
    "nerf_stage1_val.json",
    "nerf_stage2_detail_val.json",
    "nerf_stage2_val.json",
)
# Results of no trained model, and what they used instead.
NO_TRAINED_MODEL = {
    "data_render.json": "none (Blender Cycles renders)",
    "diffusion_speed.json": "neural-gaffer-256 with random weights (speed only)",
    "diffusion_steps.json": "the tiny preset with random weights (sampler convergence only)",
    "envmap_filters.json": "none (gaffer-envmap filters)",
    "envmap_preprocess.json": "none (gaffer-envmap preprocessing)",
    "nerf.json": "tiny random-init diffusion model (gaffer_nerf.guidance.smoke_model): timings only",
    "nerf_l1_val.json": "none (TensoRF fits)",
    "nerf_sizing.json": "none (TensoRF fits)",
    "nerf_sizing_real.json": "none (TensoRF fits)",
    "nerf_sizing_real_seeds.json": "none (TensoRF fits)",
    "nerf_sizing_real_val.json": "none (TensoRF fits)",
    "nerf_sizing_real_val_b.json": "none (TensoRF fits)",
    "nerf_sizing_real_val_seeds.json": "none (TensoRF fits)",
}
# Results of a dataset kept in git, and its manifest.
DATA_AT_COMMIT = {
    "demo_example_gaffer-tiny-0.5.1.json": (
        "packages/gaffer-diffusion/src/gaffer_diffusion/data/example/dataset.json"
    ),
    "demo_example_gaffer-tiny-0.6.json": (
        "packages/gaffer-diffusion/src/gaffer_diffusion/data/example/dataset.json"
    ),
    "demo_example_gaffer-tiny-0.7.json": (
        "packages/gaffer-diffusion/src/gaffer_diffusion/data/example/dataset.json"
    ),
}
# Training-run checkpoints scored during training and not kept: no weights file to hash.
UNKEPT_CHECKPOINTS = {
    "gaffer_tiny_training.json": (
        "unreleased training checkpoints of the gaffer-tiny 0.3 recipe (64 px and 128 px runs), "
        "scored during training; the checkpoints were not kept, so no weights sha256 exists"
    ),
}


def _git(*args: str) -> str:
    return subprocess.run(
        ["git", *args], cwd=REPO, capture_output=True, check=True, text=False
    ).stdout.decode("utf-8", "replace")


def _git_bytes(*args: str) -> bytes:
    return subprocess.run(["git", *args], cwd=REPO, capture_output=True, check=True).stdout


def _added_in(path: Path) -> str | None:
    log = _git("log", "--format=%h", "--diff-filter=A", "--", str(path.relative_to(REPO)))
    commits = log.split()
    return commits[-1] if commits else None


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def shipped_weights() -> dict[str, str]:
    """sha256 of every weights file of the shipped gaffer-tiny folder, now."""
    root = REPO / WEIGHTS
    return {
        str(f.relative_to(REPO)): _sha256(f.read_bytes())
        for f in sorted(root.rglob("*.safetensors"))
    }


def tiny_at(commit: str) -> dict[str, Any]:
    """gaffer-tiny as it was at `commit`: its release (the card's title) and weights' sha256."""
    card = _git("show", f"{commit}:{WEIGHTS}/MODEL_CARD.md").splitlines()[0]
    m = re.match(r"#\s*(gaffer-tiny)\s+(\S+)", card)
    files = [
        line.split("\t", 1)[1]
        for line in _git("ls-tree", "-r", commit, "--", WEIGHTS).splitlines()
        if line.endswith(".safetensors")
    ]
    weights = {f: _sha256(_git_bytes("show", f"{commit}:{f}")) for f in files}
    return {
        "name": m.group(1) if m else "gaffer-tiny",
        "version": m.group(2) if m else "unknown",
        "shipped": weights == shipped_weights(),
        "weights_sha256": weights,
        "source": f"git: {WEIGHTS} at {commit} (the card's title names the release)",
    }


def data_at(commit: str, manifest: str) -> dict[str, Any]:
    """A dataset in git as it was at `commit`: its folder, manifest and the manifest's sha256."""
    return {
        "path": str(Path(manifest).parent),
        "manifest": Path(manifest).name,
        "manifest_sha256": _sha256(_git_bytes("show", f"{commit}:{manifest}")),
        "source": f"git: {manifest} at {commit}",
    }


def provenance(path: Path, doc: dict[str, Any]) -> dict[str, Any]:
    recorded = doc.get("machine")
    machine: dict[str, Any] = recorded if isinstance(recorded, dict) else {}
    commit = machine.get("git_commit")
    block: dict[str, Any] = {"backfilled_by": BY}
    if commit:
        block["code_commit"] = commit
        block["code_commit_is"] = "the HEAD the run recorded"
    else:
        block["code_commit"] = _added_in(path)
        block["code_commit_is"] = (
            "the commit that added this file (the run did not record one; its code is at or "
            "before this commit)"
        )
    block["machine"] = machine.get("device") or machine.get("cpu_model") or "not recorded"
    name = path.name
    if name in TINY_AT_COMMIT and commit:
        block["model"] = tiny_at(commit)
    elif name in NO_TRAINED_MODEL:
        block["model"] = {"trained": False, "what": NO_TRAINED_MODEL[name]}
    elif name in UNKEPT_CHECKPOINTS:
        block["model"] = {"shipped": False, "what": UNKEPT_CHECKPOINTS[name]}
    if name in DATA_AT_COMMIT and block["code_commit"]:
        block["data"] = data_at(block["code_commit"], DATA_AT_COMMIT[name])
    return block


def names_machine(doc: dict[str, Any]) -> bool:
    machine = doc.get("machine")
    return isinstance(machine, dict) and bool(
        machine.get("git_commit") and machine.get("cpu_model")
    )


def names_weights(doc: dict[str, Any]) -> bool:
    """The file itself says which weights it measured: a `model` block with weights' sha256
    (`_common.model_provenance`), a per-pair file's `settings.unet_sha256`, or every row's."""
    model = doc.get("model")
    if isinstance(model, dict) and model.get("weights_sha256"):
        return True
    settings = doc.get("settings")
    if isinstance(settings, dict) and settings.get("unet_sha256"):
        return True
    rows = doc.get("rows")
    return (
        isinstance(rows, list)
        and bool(rows)
        and all(isinstance(r, dict) and r.get("unet_sha256") for r in rows)
    )


def needs_block(doc: dict[str, Any]) -> bool:
    """A file that names its commit, machine and weights itself needs no block."""
    return not (names_machine(doc) and names_weights(doc))


def states_model(doc: dict[str, Any]) -> bool:
    """The file says in its own words which model it ran (`model` or `config.model`): enough for a
    result of a random or no model; a trained model's weights are checked by `names_weights`."""
    config = doc.get("config")
    return bool(doc.get("model")) or (isinstance(config, dict) and bool(config.get("model")))


def problems(name: str, doc: dict[str, Any]) -> list[str]:
    """What a result file fails to name (empty: it names commit, machine and model)."""
    block = doc.get("provenance") or {}
    found = []
    if not (names_machine(doc) or (block.get("code_commit") and block.get("machine"))):
        found.append(f"{name}: no code commit and machine")
    if name in TINY_AT_COMMIT and not (names_weights(doc) or isinstance(block.get("model"), dict)):
        found.append(f"{name}: a trained gaffer-tiny's result without its weights' sha256")
    if not (names_weights(doc) or isinstance(block.get("model"), dict) or states_model(doc)):
        if Path(name).name not in NO_TRAINED_MODEL:
            found.append(f"{name}: does not say which model (or none) it measured")
    data = block.get("data") if isinstance(block.get("data"), dict) else doc.get("data")
    if Path(name).name in DATA_AT_COMMIT and not (
        isinstance(data, dict) and data.get("manifest_sha256")
    ):
        found.append(f"{name}: a result of a dataset in git without its manifest's sha256")
    return found


def result_files() -> list[Path]:
    return sorted(p for p in RESULTS.rglob("*.json") if "runs" not in p.relative_to(RESULTS).parts)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 when a block is missing")
    parser.add_argument("files", nargs="*", type=Path, help="only these result files")
    args = parser.parse_args(argv)
    missing = []
    only = {f.resolve() for f in args.files}
    for path in result_files():
        if only and path.resolve() not in only:
            continue
        doc = json.loads(path.read_text())
        if not needs_block(doc):
            continue
        if args.check:
            missing += problems(str(path.relative_to(REPO)), doc)
            continue
        doc["provenance"] = provenance(path, doc)
        # keep the file's own layout: per-pair files are written with indent 1, the rest with 2
        indent = 1 if path.parent.name == "reshade" else 2
        path.write_text(json.dumps(doc, indent=indent) + "\n")
        print(f"{path.relative_to(REPO)}: {doc['provenance']['code_commit']}")
    for m in missing:
        print(m)
    return 1 if missing else 0


if __name__ == "__main__":
    sys.exit(main())
