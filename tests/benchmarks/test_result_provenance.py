"""Every committed result file names what it measured.

Commit and machine, and for a result of a trained model its release and the sha256 of its weights; a
result of an older model says so (`shipped: false`) and never carries the shipped release's name with
other weights. New runs record this through `benchmarks/_common.py`; files from before carry a
`provenance` block written by `benchmarks/backfill_provenance.py` from git.
"""

import hashlib
import importlib.util
import json
import sys
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "benchmarks" / "results"
SHIPPED = ROOT / "packages/gaffer-diffusion/src/gaffer_diffusion/weights/gaffer-tiny"
ESTIMATOR = ROOT / "packages/gaffer-diffusion/src/gaffer_diffusion/weights/gaffer-normals"


@pytest.fixture(scope="module")
def backfill() -> ModuleType:
    path = ROOT / "benchmarks" / "backfill_provenance.py"
    spec = importlib.util.spec_from_file_location("backfill_provenance", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["backfill_provenance"] = module
    spec.loader.exec_module(module)
    return module


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _shipped_release() -> str:
    release = json.loads((SHIPPED / "gaffer_model.json").read_text())["release"]
    return f"{release['name']} {release['version']}"


def _docs() -> list[tuple[str, dict[str, Any]]]:
    return [
        (str(p.relative_to(ROOT)), json.loads(p.read_text()))
        for p in sorted(RESULTS.rglob("*.json"))
        if "runs" not in p.relative_to(RESULTS).parts
    ]


def _models(doc: dict[str, Any]) -> list[dict[str, Any]]:
    """Every model identity a file states: a `model` block, a provenance block's, per-pair settings,
    summary rows."""
    found = []
    for block in (doc.get("model"), (doc.get("provenance") or {}).get("model")):
        if isinstance(block, dict):
            found.append(block)
    settings = doc.get("settings")
    if isinstance(settings, dict) and "unet_sha256" in settings:
        found.append(settings)
    for row in doc.get("rows") or []:
        if isinstance(row, dict) and "unet_sha256" in row:
            found.append(row)
    return found


def test_every_result_file_names_its_commit_machine_and_model(backfill: ModuleType) -> None:
    docs = _docs()
    assert len(docs) > 20
    problems = [problem for name, doc in docs for problem in backfill.problems(name, doc)]
    assert not problems, "\n".join(problems)


def test_a_result_that_claims_the_shipped_model_measured_its_weights() -> None:
    shipped = _shipped_release()
    unet = _sha(SHIPPED / "unet" / "diffusion_pytorch_model.safetensors")
    estimator = _sha(ESTIMATOR / "unet" / "diffusion_pytorch_model.safetensors")
    for name, doc in _docs():
        for model in _models(doc):
            release = model.get("release") or f"{model.get('name')} {model.get('version')}"
            claims = model.get("shipped") is True or release == shipped
            shas = set((model.get("weights_sha256") or {}).values()) | {model.get("unet_sha256")}
            if claims:
                assert unet in shas, f"{name}: says {shipped} / shipped but measured other weights"
                named = set((model.get("normal_estimator_weights_sha256") or {}).values())
                named |= {model.get("normal_estimator_sha256")} - {None}
                assert not named or estimator in named, f"{name}: another normal estimator"
            elif "shipped" in model:
                # an older release or a checkpoint says so
                assert model["shipped"] is False, name


def test_the_rerun_benchmarks_measured_the_shipped_model() -> None:
    for result in ("diffusion_quality.json", "detail_transfer.json"):
        doc = json.loads((RESULTS / result).read_text())
        model = doc["model"]
        assert model["shipped"] is True, result
        assert f"{model['name']} {model['version']}" == _shipped_release(), result
        assert doc["data"]["manifest_sha256"], result
        assert doc["machine"]["git_commit"] and doc["machine"]["cpu_model"], result


def test_backfill_check_passes(backfill: ModuleType) -> None:
    assert backfill.main(["--check"]) == 0


def test_problems_names_what_is_missing(backfill: ModuleType) -> None:
    assert backfill.problems("x.json", {"model": "tiny random-init"}) == [
        "x.json: no code commit and machine"
    ]
    machine = {"machine": {"git_commit": "abc1234", "cpu_model": "some CPU"}}
    assert backfill.problems("x.json", machine) == [
        "x.json: does not say which model (or none) it measured"
    ]
    # a trained gaffer-tiny's result must name its weights, not just a model name
    assert backfill.problems("nerf_real.json", {**machine, "model": "gaffer-tiny"}) == [
        "nerf_real.json: a trained gaffer-tiny's result without its weights' sha256"
    ]


def test_a_result_of_the_shipped_example_names_its_manifest(backfill: ModuleType) -> None:
    name = "demo_example_gaffer-tiny-0.7.json"
    doc = {"machine": {"git_commit": "abc1234", "cpu_model": "some CPU"}}
    doc["model"] = {"weights_sha256": {"unet.safetensors": "0" * 64}}
    assert backfill.problems(name, doc) == [
        f"{name}: a result of a dataset in git without its manifest's sha256"
    ]
    # the committed file names the manifest it was measured on, as git has it at its commit
    committed = json.loads((RESULTS / name).read_text())
    data = committed["provenance"]["data"]
    manifest = ROOT / data["path"] / data["manifest"]
    assert data["manifest_sha256"] == _sha(manifest), "the example's manifest changed since the run"
