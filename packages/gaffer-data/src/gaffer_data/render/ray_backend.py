"""The Ray backend of `gaffer-data render --backend ray`: one Ray task per object.

Each task runs `gaffer_data.render.runner.render_object`, the same function as the local backend, so the
plans, resume markers, manifests and images are identical for the same seed; only where an object runs
changes. Blender still runs in its own worker subprocess inside the task, so a crashing object fails
its attempt (and is retried) without killing the Ray worker; the worker subprocess dies with its
parent (PR_SET_PDEATHSIG), so a Ray worker that is killed leaves no orphan writing into the folder.

On a multi-node cluster every node needs `gaffer-data[render,ray]` installed, and the objects, env maps
and the output folder must be on a shared filesystem under the same absolute paths. Tasks are spread over
the nodes (Ray's SPREAD strategy: each is a whole Blender render, so filling one node first only queues
them there). A node that dies mid-object fails its task with a system error; Ray re-runs it on a live
node (`max_retries`), where `render_object` cleans the dead attempt's temporaries, keeps its finished
images and writes the manifest last, so nothing half-written is ever published (tested on a simulated
two-node cluster: tests/test_ray_multinode.py).

Ray's usage statistics are switched off (`RAY_USAGE_STATS_ENABLED=0` before `ray.init`): a render farm
run by this tool never phones home. A cluster started with `ray start` decides that for itself.
"""

import logging
import os
import sys
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from types import ModuleType

from gaffer_data.dataset.schema import FailureRecord, ObjectPlan
from gaffer_data.errors import ClusterError, ConfigError, MissingDependencyError
from gaffer_data.render.runner import ObjectResult, RunOptions, render_object

logger = logging.getLogger(__name__)

RAY_ADDRESS_ENV = "RAY_ADDRESS"
USAGE_STATS_ENV = "RAY_USAGE_STATS_ENABLED"


def import_ray() -> ModuleType:
    """Import `ray` or say how to install it.

    Raises:
        MissingDependencyError: ray is not installed.
    """
    try:
        import ray  # pyright: ignore[reportMissingImports]  # extra [ray], absent in `nox -s typecheck`
    except ImportError as exc:
        raise MissingDependencyError(
            "`--backend ray` needs `ray`, which is not installed. "
            'Install it with: pip install "gaffer-data[ray]" (or render with `--backend local`).'
        ) from exc
    return ray


@dataclass(frozen=True, kw_only=True)
class RayOptions:
    """Where and how big the Ray tasks are (none of it changes the images).

    Attributes:
        address: the cluster to join (`ray.init(address=...)`, e.g. "auto" or "HEAD_IP:6379");
            None reads `RAY_ADDRESS`, and without it a local Ray instance with
            `workers * cpus_per_task` CPUs is started for the run and shut down after it.
        cpus_per_task: Ray `num_cpus` of each object's task, also its Cycles thread count unless the
            render config fixes `threads`; None uses the local backend's share, `cpu_count // workers`.
    """

    address: str | None = None
    cpus_per_task: int | None = None

    def __post_init__(self) -> None:
        if self.cpus_per_task is not None and self.cpus_per_task < 1:
            raise ConfigError(f"`cpus_per_task`={self.cpus_per_task} must be >= 1.")


def _render_object_task(
    plan: ObjectPlan, out: str, options: RunOptions, threads: int, python: str | None
) -> tuple[ObjectResult, str]:
    # Runs inside a Ray worker, possibly on another node: start Blender with that node's interpreter
    # unless the caller chose one explicitly. Returns the result and the id of the node that ran it.
    import ray  # pyright: ignore[reportMissingImports]  # present in a Ray worker

    options = replace(options, python=python or sys.executable)
    node = str(ray.get_runtime_context().get_node_id())
    return render_object(plan, Path(out), options, threads), node


class RayDispatch:
    """A `gaffer_data.render.runner.Dispatch` that runs one Ray task per object.

    Ray's own `max_retries` (= `RunOptions.retries`) re-runs a task whose Ray worker or node died; a
    Blender failure is retried inside the task, as in the local backend. A task that still fails is
    recorded like any failed object, and the run goes on.

    Raises:
        MissingDependencyError: ray is not installed (raised on construction).
        ClusterError: the cluster cannot be joined (raised when the run starts).
    """

    def __init__(self, ray_options: RayOptions | None = None) -> None:
        self.ray_options = ray_options or RayOptions()
        self._ray = import_ray()
        self.object_nodes: dict[str, str] = {}
        """The Ray node id each object of the last run finished on (for logs and post-mortems)."""

    def _connect(self, num_cpus: int) -> bool:
        """Join or start Ray; True when this call started it (and the run must shut it down)."""
        ray = self._ray
        if ray.is_initialized():
            return False
        # read by ray.init (and inherited by a local instance's raylets and workers)
        os.environ[USAGE_STATS_ENV] = "0"
        address = self.ray_options.address or os.environ.get(RAY_ADDRESS_ENV) or None
        if address is not None:
            logger.info("joining the Ray cluster at %s", address)
            try:
                ray.init(address=address)
            except (ConnectionError, RuntimeError) as exc:
                raise ClusterError(
                    f"cannot join the Ray cluster at `--ray-address`={address!r} ({exc}). Check "
                    "`ray status` on its head node; for a `ray start` cluster on this machine, "
                    "`--ray-address auto` also works; without `--ray-address` and "
                    f"{RAY_ADDRESS_ENV} a local instance is started."
                ) from exc
        else:
            # address="local": a fresh instance even when a `ray start` cluster runs on this machine.
            logger.info("starting a local Ray instance with %d CPUs", num_cpus)
            ray.init(address="local", num_cpus=num_cpus, include_dashboard=False)
        return True

    def __call__(
        self,
        plans: Sequence[ObjectPlan],
        out: Path,
        options: RunOptions,
        threads: int,
        on_image: Callable[[float], None],
    ) -> Iterator[ObjectResult]:
        """Submit every plan as a Ray task and yield the results as the tasks finish."""
        if not plans:
            return
        ray = self._ray
        num_cpus = self.ray_options.cpus_per_task or threads
        blender_threads = plans[0].config.threads or num_cpus
        # The driver's default interpreter may not exist on other nodes; only pass an explicit one.
        python = options.python if options.python != sys.executable else None
        root = str(Path(out).resolve())
        started = False
        pending: list[object] = []
        try:
            started = self._connect(num_cpus * options.workers)
            task = ray.remote(_render_object_task).options(
                num_cpus=num_cpus,
                max_retries=options.retries,
                retry_exceptions=False,
                scheduling_strategy="SPREAD",
            )
            self.object_nodes = {}
            refs = {task.remote(p, root, options, blender_threads, python): p for p in plans}
            pending = list(refs)
            while pending:
                # Whatever finished within a second: one wait per object would be O(N^2) for big runs.
                done, pending = ray.wait(pending, num_returns=len(pending), timeout=1.0)
                for ref in done:
                    result = self._result(ref, refs[ref], options)
                    for seconds in result.image_seconds:
                        on_image(seconds)
                    yield result
        finally:
            # Interrupted (Ctrl-C, an error in the caller): stop the rest; force kills the Ray worker,
            # and with it the Blender subprocess. A rerun resumes what was started.
            for ref in pending:
                ray.cancel(ref, force=True)
            if started:
                ray.shutdown()

    def _result(self, ref: object, plan: ObjectPlan, options: RunOptions) -> ObjectResult:
        try:
            result, node = self._ray.get(ref)
            self.object_nodes[plan.object_id] = node
            logger.debug("%s ran on Ray node %s", plan.object_id, node)
            return result  # type: ignore[no-any-return]
        except self._ray.exceptions.RayError as exc:
            reason = f"the Ray task failed: {type(exc).__name__}: {str(exc).strip()[:2000]}"
            logger.warning("%s: %s", plan.object_id, reason)
            failure = FailureRecord(
                object_id=plan.object_id,
                source=plan.source,
                attempts=options.retries + 1,
                reason=reason,
            )
            return ObjectResult(object_id=plan.object_id, failure=failure, image_seconds=())
