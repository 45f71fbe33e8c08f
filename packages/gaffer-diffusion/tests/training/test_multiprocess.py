"""Training on several processes: 2 CPU processes in one gloo group, launched as a user
launches them (`accelerate launch --multi_gpu --num_processes 2 -m gaffer_diffusion.cli train`).

- 2 processes of batch 1 train as 1 process of batch 2 (same global batch, same data stream): every
  sample's randomness is keyed by its position in the stream (`objective.ItemRandom`), so the weights
  match up to float rounding (batched vs unbatched kernels);
- `--resume` changes the process count both ways (2 -> 1, 1 -> 2) and still matches;
- `kill -9` of one rank ends the launch non-zero (no hang) and leaves the last published checkpoint
  complete and resumable.

Note: `accelerate launch --cpu --num_processes 2` starts ONE process (accelerate's multi-CPU launch
needs MPI); `--multi_gpu` starts them with torchrun, and `train` joins them over gloo on a CPU.
Tiny random model, 32 px, 4 training views; one thread per process (2 shared cores).
"""

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import uuid
from pathlib import Path
from typing import Any

import pytest
import torch

pytest.importorskip("gaffer_data")
pytest.importorskip("accelerate")

if sys.platform != "linux":  # kill -9 and /proc
    pytest.skip("multi-process training tests run on Linux", allow_module_level=True)

from gaffer_diffusion.training import checkpoint as ckpt
from gaffer_diffusion.training import load_checkpoint_model, train
from gaffer_diffusion.training.config import TrainConfig
from gaffer_diffusion.training.loop import build_training_model
from gaffer_diffusion.training.testing import tiny_train_config, write_synthetic_dataset

LAUNCH_TIMEOUT_S = 240.0
"""Generous: two processes importing torch on a loaded 2-core CI machine; a hang fails well before."""

MAX_RELATIVE_DIFFERENCE = 1e-2
"""Bound on |w_two - w_one| / |w_one - w_init| over all UNet weights (global L2 norms). Elementwise
tolerances do not apply: the cross-attention query/key weights (and the norm before them) have a zero
true gradient (one CLIP token: the softmax over one key is 1), so AdamW moves them by its normalised
float noise, differently for every batch layout. Measured 7.9e-4 for 2 processes vs 1; a
different noise or data order (per-process randomness, as before) gives ~1.1."""


@pytest.fixture(autouse=True)
def one_thread():
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(old)


@pytest.fixture(scope="module")
def data_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_synthetic_dataset(
        tmp_path_factory.mktemp("mp") / "data", objects=3, views=2, lightings=3
    )


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _write_config(path: Path, out: Path, root: Path, **train: Any) -> Path:
    cfg = tiny_train_config(out, root, train=train, checkpoint={"every_steps": 2, "keep": 3})
    path.write_text(json.dumps(cfg.to_dict()))
    return path


def _launch(config: Path, *extra: str, tag: str) -> subprocess.Popen[str]:
    """`accelerate launch --multi_gpu --num_processes 2 -m gaffer_diffusion.cli train` on the CPU."""
    env = {
        **os.environ,
        "CUDA_VISIBLE_DEVICES": "",
        "OMP_NUM_THREADS": "1",
        "MKL_NUM_THREADS": "1",
        "GAFFER_TEST_LAUNCH": tag,  # inherited by the ranks: how the kill test finds them
    }
    cmd = [
        sys.executable,
        "-m",
        "accelerate.commands.accelerate_cli",
        "launch",
        "--multi_gpu",
        "--num_processes",
        "2",
        "--num_machines",
        "1",
        "--mixed_precision",
        "no",
        "--dynamo_backend",
        "no",
        "--main_process_port",
        str(_free_port()),
        "-m",
        "gaffer_diffusion.cli",
        "train",
        "--config",
        str(config),
        *extra,
    ]
    return subprocess.Popen(
        cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )


def _finish(proc: subprocess.Popen[str]) -> tuple[int, str]:
    try:
        out, _ = proc.communicate(timeout=LAUNCH_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
        pytest.fail(f"the launch hung past {LAUNCH_TIMEOUT_S} s:\n{out[-3000:]}")
    return proc.returncode, out


def _rank_pid(tag: str, rank: int) -> int | None:
    """The pid of rank `rank` of the launch tagged `tag` (from the processes' environments)."""
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            env = (d / "environ").read_bytes().split(b"\0")
        except OSError:
            continue
        if f"GAFFER_TEST_LAUNCH={tag}".encode() in env and f"RANK={rank}".encode() in env:
            if b"LOCAL_RANK=%d" % rank in env:  # a rank, not the launcher
                return int(d.name)
    return None


def _unet(checkpoint: Path, *, ema: bool) -> dict[str, torch.Tensor]:
    model = load_checkpoint_model(checkpoint, use_ema=ema)
    return {k: v.detach() for k, v in model.unet.state_dict().items()}


def _assert_same_weights(a: Path, b: Path) -> None:
    """The raw and EMA UNets of checkpoints `a` and `b` agree (see `MAX_RELATIVE_DIFFERENCE`)."""
    cfg = TrainConfig.from_dict(ckpt.read_state(a).config)
    w0 = build_training_model(cfg.model).unet.state_dict()
    for ema in (False, True):
        wa, wb = _unet(a, ema=ema), _unet(b, ema=ema)
        assert wa.keys() == wb.keys()
        diff = torch.stack([(wb[k] - wa[k]).norm() for k in wa]).norm()
        moved = torch.stack([(wa[k] - w0[k]).norm() for k in wa]).norm()
        assert moved > 0
        rel = float(diff / moved)
        assert rel < MAX_RELATIVE_DIFFERENCE, f"{b} differs from {a} by {rel:.2e} (ema={ema})"


def _copy_checkpoint(src: Path, out: Path) -> None:
    (out / "checkpoints").mkdir(parents=True)
    shutil.copytree(src, out / "checkpoints" / src.name)


def test_two_processes_train_as_one_and_resume_across_process_counts(
    tmp_path: Path, data_root: Path
) -> None:
    # reference: one process, global batch 2, steps 1..4 (checkpoints at 2 and 4)
    ref = train(tiny_train_config(tmp_path / "one", data_root, checkpoint={"every_steps": 2}))
    assert ref.step == 4 and ref.checkpoint is not None
    ref2 = tmp_path / "one" / "checkpoints" / ckpt.checkpoint_name(2)
    ref4 = ref.checkpoint

    # two processes of batch 1: the same global batch and data stream
    two = _write_config(tmp_path / "two.json", tmp_path / "two", data_root, batch_size=1)
    rc, log = _finish(_launch(two, tag=uuid.uuid4().hex))
    assert rc == 0, log[-3000:]
    assert log.count("trained steps 0 -> 4 (max_steps)") == 2, log[-3000:]  # both ranks trained
    two4 = ckpt.latest_checkpoint(tmp_path / "two" / "checkpoints")
    assert two4 is not None
    state = ckpt.read_state(two4)
    assert (state.step, state.samples_seen, state.world_size) == (4, 8, 2)
    assert {p.name for p in two4.glob("random_states_*.pkl")} == {
        "random_states_0.pkl",
        "random_states_1.pkl",
    }  # both ranks wrote theirs before the folder was published
    assert not list((tmp_path / "two" / "checkpoints").glob(".tmp-*"))
    assert (tmp_path / "two" / "final" / "gaffer_model.json").is_file()
    _assert_same_weights(ref4, two4)

    # 2 -> 1: the 2-process step-2 checkpoint resumed by one process of batch 2
    _copy_checkpoint(tmp_path / "two" / "checkpoints" / ckpt.checkpoint_name(2), tmp_path / "r21")
    r21 = train(tiny_train_config(tmp_path / "r21", data_root), resume=True)
    assert (r21.start_step, r21.step) == (2, 4) and r21.checkpoint is not None
    _assert_same_weights(ref4, r21.checkpoint)

    # 1 -> 2: the 1-process step-2 checkpoint resumed by two processes of batch 1
    _copy_checkpoint(ref2, tmp_path / "r12")
    r12 = _write_config(tmp_path / "r12.json", tmp_path / "r12", data_root, batch_size=1)
    rc, log = _finish(_launch(r12, "--resume", tag=uuid.uuid4().hex))
    assert rc == 0, log[-3000:]
    assert log.count("trained steps 2 -> 4 (max_steps)") == 2, log[-3000:]
    r12_4 = ckpt.latest_checkpoint(tmp_path / "r12" / "checkpoints")
    assert r12_4 is not None and ckpt.read_state(r12_4).world_size == 2
    _assert_same_weights(ref4, r12_4)


def test_kill_9_of_one_rank_ends_the_launch_and_leaves_a_resumable_checkpoint(
    tmp_path: Path, data_root: Path
) -> None:
    out = tmp_path / "run"
    # many steps, a checkpoint every step: the kill lands mid-run, possibly mid-save
    cfg = tiny_train_config(
        out, data_root, train={"max_steps": 500, "batch_size": 1}, checkpoint={"every_steps": 1}
    )
    config = tmp_path / "run.json"
    config.write_text(json.dumps(cfg.to_dict()))
    tag = uuid.uuid4().hex
    proc = _launch(config, tag=tag)
    deadline = time.monotonic() + LAUNCH_TIMEOUT_S
    victim = None
    while time.monotonic() < deadline and proc.poll() is None:
        done = ckpt.latest_checkpoint(out / "checkpoints")
        if done is not None and ckpt.read_state(done).step >= 3:
            victim = _rank_pid(tag, 1)
            break
        time.sleep(0.05)
    assert victim is not None, f"no checkpoint or rank 1 found (rc {proc.poll()})"
    os.kill(victim, signal.SIGKILL)
    t_kill = time.monotonic()
    rc, log = _finish(proc)
    assert rc != 0, log[-3000:]
    assert time.monotonic() - t_kill < 60, "the launch took over a minute to end after the kill"
    assert _rank_pid(tag, 0) is None  # no rank left behind

    last = ckpt.latest_checkpoint(out / "checkpoints")
    assert last is not None
    step = ckpt.read_state(last).step
    assert 3 <= step < 500
    # resumable: one process (global batch 2, as the run's) continues it two steps
    cfg2 = tiny_train_config(
        out,
        data_root,
        train={"max_steps": step + 2, "batch_size": 2},
        checkpoint={"every_steps": 1},
    )
    resumed = train(cfg2, resume=True)
    assert (resumed.start_step, resumed.step) == (step, step + 2)
    assert all(torch.isfinite(torch.tensor(resumed.losses)))
    assert not list((out / "checkpoints").glob(".tmp-*"))  # the killed run's leftovers removed
