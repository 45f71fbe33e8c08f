"""Run a dataset render: shard, plan, dispatch objects to Blender worker subprocesses, write manifests.

Resumability: an object is complete iff `objects/<id>/manifest.json` exists; it is written atomically
after every payload was written atomically and hashed. A rerun skips complete objects, cleans temporary
files of killed writers, keeps the finished images of an interrupted object (its plan is deterministic)
and renders only what is missing. A worker that fails is retried; an object that still fails is recorded
in `dataset.json` and `failures.jsonl`, and the run goes on.

Concurrent runs into one folder (the same command started twice, or shards sharing storage) share the
work: each object is rendered under an exclusive lock (`.locks/<id>.lock`, POSIX `flock`), an object
locked by another process is left to it (recorded as "busy", picked up by a rerun if that process dies),
and one finished meanwhile is not rendered again. Without the lock, one run's clean-up of temporaries
would delete the other's files in flight.
"""

import concurrent.futures
import contextlib
import dataclasses
import json
import logging
import os
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from gaffer_data._atomic import atomic_write, atomic_write_json, remove_stale_temporaries
from gaffer_data.config import RenderConfig
from gaffer_data.dataset.manifest import (
    object_manifest_json,
    plan_to_json,
    producer,
    read_json,
    sha256_file,
    utc_now,
)
from gaffer_data.dataset.reader import DATASET_NAME, MANIFEST_NAME, OBJECTS_DIR
from gaffer_data.dataset.schema import (
    DATASET_SCHEMA,
    DATASET_SCHEMA_VERSION,
    FailureRecord,
    FileRecord,
    Normalization,
    ObjectPlan,
)
from gaffer_data.errors import ConfigError, InputError, ManifestError
from gaffer_data.render.plan import (
    PoolEntry,
    check_pool_maps,
    check_pool_pixels,
    nerf_transforms,
    plan_for,
    plan_poses,
    stable_object_hash,
)
from gaffer_data.render.worker import EVENT_PREFIX, NORMALIZATION_NAME

logger = logging.getLogger(__name__)

PLAN_NAME = "_plan.json"
FAILURES_NAME = "failures.jsonl"
LOCKS_DIR = ".locks"
_PAYLOAD_DIRS = ("lit", "area", "alpha", "normal", "albedo", "depth", ".scratch")


@dataclass(frozen=True, kw_only=True)
class Shard:
    """Shard `index` of `count`: the objects whose id hash is `index` modulo `count` (job arrays)."""

    index: int = 0
    count: int = 1

    def __post_init__(self) -> None:
        if not 0 <= self.index < self.count:
            raise ConfigError(
                f"`shard`={self.index}/{self.count} is invalid; use i/N with 0 <= i < N, e.g. 0/4."
            )

    @classmethod
    def parse(cls, text: str) -> "Shard":
        """Parse "i/N".

        Raises:
            ConfigError: not of the form i/N.
        """
        try:
            index, count = (int(p) for p in text.split("/"))
        except ValueError as exc:
            raise ConfigError(f"`--shard`={text!r} is not of the form i/N (e.g. 0/4).") from exc
        return cls(index=index, count=count)

    def contains(self, object_id: str) -> bool:
        """Whether this shard renders `object_id` (stable under adding or removing objects)."""
        return stable_object_hash(object_id) % self.count == self.index


@dataclass(frozen=True, kw_only=True)
class RunOptions:
    """How a render run executes (none of it changes the images).

    Attributes:
        workers: Blender worker subprocesses running at once.
        retries: extra attempts for a failing object before it is recorded as failed.
        timeout_s: wall-clock limit per worker attempt, or None.
        shard: which share of the objects this run renders.
        progress: show a tqdm progress bar on stderr.
        python: interpreter that runs the workers (the current one by default).
    """

    workers: int = 1
    retries: int = 1
    timeout_s: float | None = None
    shard: Shard = field(default_factory=Shard)
    progress: bool = True
    python: str = sys.executable

    def __post_init__(self) -> None:
        if self.workers < 1 or self.retries < 0:
            raise ConfigError(
                f"`workers`={self.workers} must be >= 1 and `retries`={self.retries} >= 0."
            )


@dataclass(frozen=True, kw_only=True)
class RunSummary:
    """What a run did.

    Attributes:
        rendered: objects completed by this run.
        skipped: objects already complete before this run.
        failed: objects given up on in this run.
        images: images rendered by this run.
        seconds: wall-clock time of the run.
        image_seconds: per-image render times reported by the workers.
    """

    rendered: tuple[str, ...]
    skipped: tuple[str, ...]
    failed: tuple[FailureRecord, ...]
    images: int
    seconds: float
    image_seconds: tuple[float, ...]


@dataclass(frozen=True, kw_only=True)
class ObjectResult:
    """What `render_object` did for one object (the unit of work of every backend).

    Attributes:
        object_id: the object.
        failure: None when the object is complete, else why it was given up on.
        image_seconds: per-image render times reported by the workers, all attempts included.
    """

    object_id: str
    failure: FailureRecord | None
    image_seconds: tuple[float, ...]


@runtime_checkable  # so the test-time type hook (beartype) can check `dispatch=` arguments
class Dispatch(Protocol):
    """Runs `render_object` for each plan and yields the results as objects finish (any order).

    `on_image(seconds)` is called once per rendered image, from any thread, as soon as the backend
    knows of it. `dispatch_local` is the default; `gaffer_data.render.ray_backend.RayDispatch`
    spreads the objects over a Ray cluster.
    """

    def __call__(
        self,
        plans: Sequence[ObjectPlan],
        out: Path,
        options: "RunOptions",
        threads: int,
        on_image: Callable[[float], None],
    ) -> Iterator[ObjectResult]: ...


def _file_records(plan: ObjectPlan, root: Path) -> list[FileRecord]:
    r = plan.config.resolution
    records: list[FileRecord] = []

    def add(path: str | None, kind: str, dtype: str, shape: tuple[int, ...], space: str) -> None:
        if path is None:
            return
        if not (root / path).is_file():
            raise ManifestError(f"the worker finished but `{root / path}` is missing.")
        records.append(
            FileRecord(
                path=path,
                sha256=sha256_file(root / path),
                kind=kind,  # type: ignore[arg-type]
                dtype=dtype,
                shape=shape,
                color_space=space,  # type: ignore[arg-type]
            )
        )

    add("cameras.npz", "cameras", "npz", (), "data")
    for split in transforms_splits(plan):
        add(f"transforms_{split}.json", "transforms", "json", (), "data")
    for view in plan.views:
        for lit in view.lit:
            add(lit.exr, "lit_exr", "float32", (r, r, 4), "linear_rec709")
            add(lit.png, "lit_png", "uint8", (r, r, 4), "srgb")
        if view.area is not None:
            add(view.area.exr, "area_exr", "float32", (r, r, 4), "linear_rec709")
            add(view.area.png, "area_png", "uint8", (r, r, 4), "srgb")
            add(view.area.normal, "normal", "float32", (r, r, 3), "data")
            add(view.area.albedo, "albedo", "float32", (r, r, 3), "linear_rec709")
            add(view.area.depth, "depth", "float32", (r, r), "data")
        add(view.alpha, "alpha", "uint8", (r, r), "data")
    return records


def _count_images(plan: ObjectPlan) -> int:
    return sum(len(v.lit) + (v.area is not None) for v in plan.views)


def _prepare_folder(plan: ObjectPlan, root: Path) -> None:
    """Clean temporaries; wipe payloads made from a different plan; write the plan and the poses."""
    root.mkdir(parents=True, exist_ok=True)
    remove_stale_temporaries(root)
    body = plan_to_json(plan)
    plan_path = root / PLAN_NAME
    if plan_path.is_file():
        try:
            same = read_json(plan_path) == json.loads(json.dumps(body))
        except ManifestError:
            same = False
        if not same:
            logger.warning(
                "%s: plan changed since the last run; re-rendering it from scratch", plan.object_id
            )
            for name in _PAYLOAD_DIRS:
                shutil.rmtree(root / name, ignore_errors=True)
    atomic_write_json(plan_path, body)
    poses = plan_poses(plan)

    def write_npz(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            np.savez(
                fh,
                w2c_blender=poses.w2c_blender,
                c2w_opencv=poses.c2w_opencv,
                intrinsics=poses.intrinsics,
            )

    atomic_write(root / "cameras.npz", write_npz)


def _run_worker(
    plan: ObjectPlan,
    root: Path,
    options: RunOptions,
    threads: int,
    on_image: Callable[[float], None],
) -> tuple[bool, str]:
    """One worker attempt; returns (success, reason)."""
    cmd = [options.python, "-m", "gaffer_data.render.worker", "--job", str(root / PLAN_NAME)]
    cmd += ["--threads", str(threads)]
    log_path = root / "_worker.log"
    reason = "the worker exited without a reason"
    with (
        open(log_path, "ab") as log,
        subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, text=True, bufsize=1) as proc,
    ):
        timer = None
        if options.timeout_s is not None:
            timer = threading.Timer(options.timeout_s, proc.kill)
            timer.start()
        if proc.stdout is None:  # internal: we asked for a pipe
            raise RuntimeError("internal error: the render worker has no stdout pipe")
        for line in proc.stdout:
            if not line.startswith(EVENT_PREFIX):
                continue
            event = json.loads(line[len(EVENT_PREFIX) :])
            if event["event"] == "image":
                on_image(float(event["seconds"]))
            elif event["event"] == "error":
                reason = f"{event['kind']}: {event['message'].strip()}"
        code = proc.wait()
        if timer is not None:
            timer.cancel()
    if code == 0:
        return True, ""
    if code < 0:
        reason = f"the worker was killed by signal {-code}"
        if options.timeout_s is not None:
            reason += f" (timeout {options.timeout_s} s?)"
    return False, f"{reason} (exit code {code}; log: {log_path})"


def transforms_splits(plan: ObjectPlan) -> tuple[str, ...]:
    """The splits that get a `transforms_{split}.json` (multi-view plans only; empty splits skipped)."""
    if plan.config.multiview is None:
        return ()
    return tuple(s for s in ("train", "test") if any(v.split == s for v in plan.views))


def _finish_object(plan: ObjectPlan, root: Path, source_sha256: str) -> None:
    for split in transforms_splits(plan):
        atomic_write_json(root / f"transforms_{split}.json", nerf_transforms(plan, split))
    norm = read_json(root / NORMALIZATION_NAME)
    manifest = object_manifest_json(
        plan,
        source_sha256=source_sha256,
        normalization=Normalization(scale=float(norm["scale"]), center=tuple(norm["center"])),  # type: ignore[arg-type]
        files=_file_records(plan, root),
    )
    atomic_write_json(root / MANIFEST_NAME, manifest)
    for name in (PLAN_NAME, NORMALIZATION_NAME, "_worker.log"):
        (root / name).unlink(missing_ok=True)


def _dataset_json(out: Path, config: RenderConfig, failures: Sequence[FailureRecord]) -> None:
    ids = sorted(p.parent.name for p in (out / OBJECTS_DIR).glob(f"*/{MANIFEST_NAME}"))
    atomic_write_json(
        out / DATASET_NAME,
        {
            "schema": DATASET_SCHEMA,
            "schema_version": DATASET_SCHEMA_VERSION,
            "producer": dataclasses.asdict(producer()),
            "created_utc": utc_now(),
            "config": config.to_dict(),
            "objects": ids,
            "failures": [dataclasses.asdict(f) for f in failures if f.object_id not in set(ids)],
        },
    )


def _check_config(
    out: Path, config: RenderConfig, *, sanitize_moot: bool = False
) -> list[FailureRecord]:
    """Refuse to mix configs in one folder; return the earlier failures.

    A render begun before `envmap_sanitize` was recorded resumes only when the policy changes no map
    of the pool (`sanitize_moot`): the workers then see the pixels they saw before.
    """
    path = out / DATASET_NAME
    if not path.is_file():
        return []
    data = read_json(path)
    ours = json.loads(json.dumps(config.to_dict()))
    theirs = data.get("config")
    if sanitize_moot and isinstance(theirs, dict) and "envmap_sanitize" not in theirs:
        theirs = {**theirs, "envmap_sanitize": ours["envmap_sanitize"]}
    if theirs != ours:
        old = theirs if isinstance(theirs, dict) else {}
        keys = sorted(k for k in set(ours) | set(old) if old.get(k, ()) != ours.get(k, ()))
        flag = " (`envmap_sanitize` is `--sanitize`)" if "envmap_sanitize" in keys else ""
        raise ConfigError(
            f"`out`={str(out)!r} was rendered with a different config (see {path}; it differs in "
            f"{', '.join(f'`{k}`' for k in keys)}); render into a new folder or pass the same "
            f"options{flag}."
        )
    return [FailureRecord(**f) for f in data.get("failures", [])]


def render_dataset(
    objects: Sequence[tuple[str, Path]],
    pool: Sequence[PoolEntry],
    out: str | Path,
    config: RenderConfig,
    options: RunOptions | None = None,
    *,
    dispatch: Dispatch | None = None,
) -> RunSummary:
    """Render every object of this shard that is not complete yet.

    Args:
        objects: `(object_id, mesh path)` pairs (see `gaffer_data.recipes.scan_objects`).
        pool: the lighting pool (`gaffer_data.render.plan.scan_envmaps`).
        out: the dataset folder (created).
        config: what to render.
        options: how to run it.
        dispatch: where the objects run (`dispatch_local` by default: worker subprocesses on this
            machine). Every backend renders each object with `render_object`, so the outputs are the
            same.

    Returns:
        A summary of the run.

    Raises:
        ConfigError: `out` holds a render made with a different config, or
            `config.augment.yaw_steps` does not divide a map's width (`check_pool_maps`).
        InputError: duplicate object ids, a map that is not 2:1, or one whose NaN/Inf/negative
            pixels `config.envmap_sanitize` refuses (`check_pool_pixels`).
    """
    options = options or RunOptions()
    out = Path(out)
    ids = [oid for oid, _ in objects]
    if len(set(ids)) != len(ids):
        raise InputError(
            "`objects` holds duplicate object ids; rename the files or use sub-folders."
        )
    if config.lightings > 0:  # before the folder exists: a 3:1 map or --yaw-steps 7 fails here
        check_pool_maps(pool, config.augment.yaw_steps)
        changed = check_pool_pixels(pool, config.envmap_sanitize)  # NaN/Inf/negatives
    else:
        changed = 0
    out.mkdir(parents=True, exist_ok=True)
    earlier = _check_config(out, config, sanitize_moot=changed == 0)
    _dataset_json(out, config, earlier)
    start = time.perf_counter()
    todo, skipped = [], []
    for oid, path in sorted(objects):
        if not options.shard.contains(oid):
            continue
        if (out / OBJECTS_DIR / oid / MANIFEST_NAME).is_file():
            skipped.append(oid)
        else:
            todo.append((oid, Path(path)))
    plans = [plan_for(oid, path, pool, config) for oid, path in todo]
    threads = config.threads or max(1, (os.cpu_count() or 1) // options.workers)
    lock = threading.Lock()
    image_seconds: list[float] = []
    bar = _progress_bar(sum(_count_images(p) for p in plans), options.progress)

    def on_image(seconds: float) -> None:
        with lock:
            image_seconds.append(seconds)
            bar.update(1)

    failures: list[FailureRecord] = []
    rendered: list[str] = []
    failures_path = out / FAILURES_NAME
    for result in (dispatch or dispatch_local)(plans, out, options, threads, on_image):
        failure = result.failure
        if failure is None:
            rendered.append(result.object_id)
        else:
            failures.append(failure)
            with lock, open(failures_path, "a", encoding="utf-8") as fh:
                fh.write(json.dumps({**dataclasses.asdict(failure), "time_utc": utc_now()}) + "\n")
        bar.set_postfix(done=len(rendered) + len(skipped), failed=len(failures))
    bar.close()
    keep = {f.object_id: f for f in earlier}
    keep.update({f.object_id: f for f in failures})
    _dataset_json(out, config, list(keep.values()))
    return RunSummary(
        rendered=tuple(sorted(rendered)),
        skipped=tuple(skipped),
        failed=tuple(failures),
        images=len(image_seconds),
        seconds=time.perf_counter() - start,
        image_seconds=tuple(image_seconds),
    )


def render_object(
    plan: ObjectPlan,
    out: Path,
    options: RunOptions,
    threads: int,
    on_image: Callable[[float], None] | None = None,
) -> ObjectResult:
    """Render one planned object into `out/objects/<id>` in Blender worker subprocesses, with retries.

    Every backend calls this, so outputs, resume behaviour and failure records do not depend on where
    an object runs. Input errors (a broken mesh) are not retried.

    Args:
        plan: the object's plan (`gaffer_data.render.plan.plan_for`).
        out: the dataset folder.
        options: `retries`, `timeout_s` and `python` are used.
        threads: Cycles threads of the worker.
        on_image: called with each image's render time as the worker reports it.

    Returns:
        The result; the object is complete (its manifest written) iff `failure` is None.
    """
    root = out / OBJECTS_DIR / plan.object_id
    seconds: list[float] = []

    def record(s: float) -> None:
        seconds.append(s)
        if on_image is not None:
            on_image(s)

    def result(failure: FailureRecord | None) -> ObjectResult:
        return ObjectResult(object_id=plan.object_id, failure=failure, image_seconds=tuple(seconds))

    source = Path(plan.source)
    if not source.is_file():
        return result(
            FailureRecord(
                object_id=plan.object_id,
                source=plan.source,
                attempts=0,
                reason="source file is missing",
            )
        )
    with _object_lock(out, plan.object_id) as held:
        if not held:
            return result(
                FailureRecord(
                    object_id=plan.object_id,
                    source=plan.source,
                    attempts=0,
                    reason="busy: another gaffer-data process is rendering this object (its lock "
                    f"{out / LOCKS_DIR / (plan.object_id + '.lock')} is held); left to it, rerun to "
                    "pick it up if that process stopped",
                )
            )
        if (root / MANIFEST_NAME).is_file():  # finished by another process since this run started
            return result(None)
        return _render_locked(plan, root, source, options, threads, record, result)


@contextlib.contextmanager
def _object_lock(out: Path, object_id: str) -> Iterator[bool]:
    """Hold an exclusive, non-blocking `flock` on the object's lock file; yield whether it was got.

    Released when the process exits however it exits. Without `fcntl` (Windows) there is no lock.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - Windows
        yield True
        return
    path = out / LOCKS_DIR / f"{object_id}.lock"
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+b") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            yield False
            return
        try:
            yield True
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _render_locked(
    plan: ObjectPlan,
    root: Path,
    source: Path,
    options: RunOptions,
    threads: int,
    record: Callable[[float], None],
    result: Callable[[FailureRecord | None], ObjectResult],
) -> ObjectResult:
    """`render_object`'s attempts, with the object's lock held."""
    source_sha = sha256_file(source)
    reason = ""
    for attempt in range(1, options.retries + 2):
        _prepare_folder(plan, root)
        ok, reason = _run_worker(plan, root, options, threads, record)
        if ok:
            try:
                _finish_object(plan, root, source_sha)
                return result(None)
            except (ManifestError, OSError) as exc:
                reason = f"finishing failed: {exc}"
        logger.warning("%s: attempt %d failed: %s", plan.object_id, attempt, reason)
        if reason.startswith("input:"):
            return result(
                FailureRecord(
                    object_id=plan.object_id, source=plan.source, attempts=attempt, reason=reason
                )
            )
    return result(
        FailureRecord(
            object_id=plan.object_id,
            source=plan.source,
            attempts=options.retries + 1,
            reason=reason,
        )
    )


def dispatch_local(
    plans: Sequence[ObjectPlan],
    out: Path,
    options: RunOptions,
    threads: int,
    on_image: Callable[[float], None],
) -> Iterator[ObjectResult]:
    """The local backend: `options.workers` objects at once, each in its own worker subprocess."""
    with concurrent.futures.ThreadPoolExecutor(max_workers=options.workers) as pool_exec:
        futures = [
            pool_exec.submit(render_object, p, out, options, threads, on_image) for p in plans
        ]
        for future in concurrent.futures.as_completed(futures):
            yield future.result()


class _NoBar:
    def update(self, n: int) -> None:
        return None

    def set_postfix(self, **kwargs: object) -> None:
        return None

    def close(self) -> None:
        return None


def _progress_bar(total: int, enabled: bool) -> "_NoBar":
    if not enabled:
        return _NoBar()
    from tqdm import tqdm

    return tqdm(total=total, unit="img", desc="render", dynamic_ncols=True)  # type: ignore[return-value]
