"""Shared plumbing for the benchmark scripts: machine description, CLI, result files, baselines.

Not a benchmark itself (`nox -s bench` runs only `bench_*.py`). Each script imports this module by
name, which works because Python puts the script's own folder first on `sys.path`.

Result files:

- every run writes `results/runs/<name>-<UTC stamp>.json` and `.png` (git-ignored);
- `--update-baseline` also writes `results/<name>.json` and `.png`: the committed baseline that
  `benchmarks/README.md` and the docs' "speed vs accuracy" page show;
- every run prints its numbers beside the committed baseline's, when one exists. Nothing fails on a
  difference: the machines these run on are shared, so timings drift (the load average is recorded).
"""

import argparse
import datetime as dt
import hashlib
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

RESULTS = Path(__file__).resolve().parent / "results"
RUNS = RESULTS / "runs"
REPO = Path(__file__).resolve().parent.parent


def parse_args(description: str, argv: Sequence[str] | None = None) -> argparse.Namespace:
    """The CLI every benchmark script shares."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--quick", action="store_true", help="short run (well under a minute)")
    parser.add_argument(
        "--update-baseline",
        action="store_true",
        help="also write results/<name>.json and .png (the committed baseline)",
    )
    parser.add_argument(
        "--threads",
        type=int,
        default=0,
        help="torch intra-op threads (default 0 = every core this process may use)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed for maps and poses")
    return parser.parse_args(argv)


def usable_cores() -> int:
    """Cores this process may run on (affinity mask), not the machine's total."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def set_threads(requested: int) -> int:
    """Set torch's intra-op thread count (0 = all usable cores) and return it."""
    n = requested if requested > 0 else usable_cores()
    torch.set_num_threads(n)
    return n


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _git_commit() -> str | None:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None


def _git_uncommitted() -> list[str] | None:
    """Source files that differ from the recorded commit (the code measured is commit + these).

    The machines are shared working trees: a run can measure code that is not yet committed, so the
    record lists it rather than claiming the commit alone. Only package and benchmark code counts.
    """
    try:
        out = subprocess.run(
            ["git", "status", "--porcelain", "--", "packages", "benchmarks", "integrations"],
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=20,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    paths = [
        line[3:]
        for line in out.stdout.splitlines()
        if line[3:].endswith(".py") and "/tests/" not in line[3:]
    ]
    return sorted(paths)


def cuda_info() -> dict[str, Any]:
    """`{"cuda": "unavailable"}` or the GPU's name and memory."""
    if not torch.cuda.is_available():
        return {"cuda": "unavailable"}
    props = torch.cuda.get_device_properties(0)
    return {
        "cuda": "available",
        "gpu": props.name,
        "gpu_memory_gib": round(props.total_memory / 2**30, 1),
        "cuda_version": torch.version.cuda,
    }


def machine(threads: int) -> dict[str, Any]:
    """What the numbers were measured on: device, cores, library versions, date, load."""
    import gaffer_envmap

    return {
        "device": f"CPU: {_cpu_model()} ({usable_cores()} usable cores)",
        "cpu_model": _cpu_model(),
        "cpu_count": usable_cores(),
        "cpu_count_machine": os.cpu_count(),
        "torch_threads": threads,
        "torch": torch.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
        "platform": platform.platform(),
        "gaffer_envmap": gaffer_envmap.__version__,
        "git_commit": _git_commit(),
        "git_uncommitted_py": _git_uncommitted(),
        "date_utc": dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "load_average_start": [round(x, 2) for x in os.getloadavg()],
        **cuda_info(),
    }


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file's bytes (read in 1 MiB chunks)."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _repo_relative(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(REPO))
    except ValueError:
        return str(path)


def model_provenance(folder: Path | None = None) -> dict[str, Any]:
    """Which model a result measured: name, release version, the sha256 of every weights file.

    `folder` is a gaffer-diffusion model folder (`save_pretrained` / `gaffer-diffusion export`);
    None means the shipped gaffer-tiny. `shipped` is True only when the folder IS the shipped one, so
    a result of an exported checkpoint or an older release never reads as the shipped model's. A model
    whose radiance hints use the learned normal estimator also names the estimator's weights, which
    change its outputs as much as its own.
    """
    from gaffer_diffusion.geometry.estimator import shipped_normal_estimator_path
    from gaffer_diffusion.pretrained import gaffer_tiny_path

    shipped_folder = gaffer_tiny_path().resolve()
    root = (folder or shipped_folder).resolve()
    manifest = json.loads((root / "gaffer_model.json").read_text())
    release = manifest.get("release") if isinstance(manifest.get("release"), dict) else None
    weights = {_repo_relative(f): sha256_file(f) for f in sorted(root.rglob("*.safetensors"))}
    if not weights:
        raise FileNotFoundError(f"{root}: no *.safetensors weights to name")
    out: dict[str, Any] = {
        "name": release["name"] if release else manifest.get("config", {}).get("name"),
        # an exported training checkpoint has no release: it is labelled so, never as a version
        "version": release["version"] if release else "unreleased checkpoint",
        "shipped": root == shipped_folder,
        "folder": _repo_relative(root),
        "weights_sha256": weights,
    }
    if manifest.get("config", {}).get("hint_geometry") == "estimated":
        est = shipped_normal_estimator_path().resolve()
        out["normal_estimator_weights_sha256"] = {
            _repo_relative(f): sha256_file(f) for f in sorted(est.rglob("*.safetensors"))
        }
    return out


def data_provenance(root: Path, manifest: str = "dataset.json") -> dict[str, Any]:
    """A render split or dataset folder named by its manifest's sha256 (it lists every object and map)."""
    path = root / manifest
    return {
        "path": _repo_relative(root),
        "manifest": manifest,
        "manifest_sha256": sha256_file(path),
    }


def model_result_header(name: str, doc: str | None, data_root: Path, **data: Any) -> dict[str, Any]:
    """The opening keys of a result that scores the shipped model on a render folder: its name, the
    script's first docstring paragraph, the model's and the data's provenance (plus `data`'s keys)."""
    return {
        "name": name,
        "description": (doc or "").split("\n\n")[0],
        "model": model_provenance(),
        "data": {**data_provenance(data_root), **data},
    }


def short_device(meta: dict[str, Any]) -> str:
    """One line for plot titles."""
    gpu = f", GPU {meta['gpu']}" if meta.get("cuda") == "available" else ", no GPU"
    load = meta.get("load_average_start", [float("nan")])[0]
    return (
        f"{meta['cpu_model']}, {meta['cpu_count']} cores{gpu}; torch {meta['torch']}, "
        f"{meta['torch_threads']} threads; {meta['date_utc'][:10]}; load avg at start {load:.1f}"
    )


@dataclass(frozen=True)
class Spread:
    """Summary of repeated measurements."""

    median: float
    q25: float
    q75: float
    min: float
    max: float
    n: int

    @classmethod
    def of(cls, values: Sequence[float]) -> "Spread":
        v = sorted(float(x) for x in values)
        if len(v) == 1:
            return cls(v[0], v[0], v[0], v[0], v[0], 1)
        q = statistics.quantiles(v, n=4, method="inclusive")
        return cls(statistics.median(v), q[0], q[2], v[0], v[-1], len(v))

    def to_dict(self) -> dict[str, float]:
        return {k: (round(x, 6) if isinstance(x, float) else x) for k, x in asdict(self).items()}


def time_calls(
    fn: Callable[[], object], calls: int, sync: Callable[[], None] | None = None
) -> float:
    """Seconds for `calls` back-to-back calls of `fn` (after `sync`, for asynchronous devices)."""
    if sync is not None:
        sync()
    t0 = time.perf_counter()
    for _ in range(calls):
        fn()
    if sync is not None:
        sync()
    return time.perf_counter() - t0


def calibrate(
    fn: Callable[[], object], min_seconds: float, sync: Callable[[], None] | None = None
) -> int:
    """Calls per repetition so that one repetition lasts at least `min_seconds` (one warm-up call first)."""
    one = time_calls(fn, 1, sync)
    return max(1, math.ceil(min_seconds / max(one, 1e-9)))


def write_results(
    name: str, payload: dict[str, Any], figure: Any, update_baseline: bool
) -> list[Path]:
    """Write the run's JSON and PNG (and the baseline's when asked); return the paths written."""
    # Recorded on the caller's dict too, so that tables built from `payload` afterwards can show it.
    payload["machine"]["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
    stamp = payload["machine"]["date_utc"].replace(":", "").replace("-", "")
    RUNS.mkdir(parents=True, exist_ok=True)
    targets = [RUNS / f"{name}-{stamp}"]
    if update_baseline:
        targets.append(RESULTS / name)
    written = []
    for base in targets:
        base.with_suffix(".json").write_text(json.dumps(payload, indent=2, sort_keys=False) + "\n")
        figure.savefig(base.with_suffix(".png"), dpi=120, bbox_inches="tight")
        written += [base.with_suffix(".json"), base.with_suffix(".png")]
    return written


def update_readme(name: str, markdown: str) -> bool:
    """Replace the block between `<!-- BEGIN name -->` and `<!-- END name -->` in benchmarks/README.md.

    Called on `--update-baseline`, so the README's "latest numbers" are the committed baseline's.
    Returns False (and changes nothing) when the markers are missing.
    """
    readme = Path(__file__).resolve().parent / "README.md"
    text = readme.read_text()
    begin, end = f"<!-- BEGIN {name} -->", f"<!-- END {name} -->"
    if begin not in text or end not in text:
        return False
    head, rest = text.split(begin, 1)
    _, tail = rest.split(end, 1)
    readme.write_text(f"{head}{begin}\n{markdown.strip()}\n{end}{tail}")
    return True


def load_baseline(name: str) -> dict[str, Any] | None:
    """The committed baseline `results/<name>.json`, or None."""
    path = RESULTS / f"{name}.json"
    if not path.exists():
        return None
    return json.loads(path.read_text())


def log(msg: str) -> None:
    """Progress goes to stderr so stdout stays a clean table."""
    print(msg, file=sys.stderr, flush=True)


def load_bundled_maps(height: int) -> dict[str, np.ndarray]:
    """Every bundled CC0 HDRI, conservatively resized to `[height, 2*height, 3]` float32 (Blender convention).

    The bundled EXRs are lossy (DWAB) and hold a few slightly negative pixels, so they are read with
    `sanitize="zero"`.
    """
    import gaffer_envmap as ge
    from gaffer_envmap.io import read_envmap

    out = {}
    for name, path in ge.bundled_hdris().items():
        env = read_envmap(path, sanitize="zero")
        out[name] = np.array(ge.resize_conservative(env, height).radiance_linear)
    return out


def random_rotations(count: int, rng: np.random.Generator) -> np.ndarray:
    """`[count, 3, 3]` rotations drawn uniformly (Haar measure) from SO(3)."""
    q, r = np.linalg.qr(rng.normal(size=(count, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    det = np.linalg.det(q)
    q[:, :, 0] *= det[:, None]  # a reflection becomes a rotation
    return q
