"""Training config: paper defaults, strict JSON parsing, shipped configs."""

import json
from pathlib import Path

import pytest

pytest.importorskip("gaffer_data")
pytest.importorskip("accelerate")

from gaffer_diffusion.errors import ConfigError
from gaffer_diffusion.training import TrainConfig, load_config

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def test_defaults_are_the_paper_recipe() -> None:
    cfg = TrainConfig.from_dict({"output_dir": "run", "data": {"root": "data"}})
    o, t, d = cfg.optim, cfg.train, cfg.data
    assert (o.lr, o.betas, o.weight_decay, o.eps, o.warmup_steps) == (
        1e-4,
        (0.9, 0.999),
        1e-2,
        1e-8,
        100,
    )
    assert o.max_grad_norm is None
    assert (t.batch_size, t.mixed_precision, t.gradient_checkpointing, t.cfg_dropout_p) == (
        64,
        "fp16",
        True,
        0.05,
    )
    assert (d.targets_per_sample, d.area_light_prob) == (2, 0.1)
    assert TrainConfig.from_dict(cfg.to_dict()) == cfg


def test_warmup_then_constant() -> None:
    o = TrainConfig.from_dict({"output_dir": "r", "data": {"root": "d"}}).optim
    assert o.lr_at(0) == pytest.approx(1e-6) and o.lr_at(49) == pytest.approx(5e-5)
    assert o.lr_at(99) == o.lr_at(10_000) == 1e-4


@pytest.mark.parametrize(
    ("patch", "match"),
    [
        ({"optim": {"lr_rate": 1}}, r"Unknown key\(s\) \['lr_rate'\] in `optim`"),
        ({"train": {"batch_size": "8"}}, "`train.batch_size` must be an integer"),
        ({"train": {"mixed_precision": "fp8"}}, "`train.mixed_precision` is 'fp8'"),
        ({"model": {"init": "zero123-xl"}}, "needs `model.path`"),
        ({"optim": {"betas": [0.9]}}, "`optim.betas` must have 2 entries"),
    ],
)
def test_bad_values_name_the_key(patch: dict, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        TrainConfig.from_dict({"output_dir": "r", "data": {"root": "d"}, **patch})


def test_missing_data_root_is_reported() -> None:
    with pytest.raises(ConfigError, match="data"):
        TrainConfig.from_dict({"output_dir": "r"})


def test_relative_paths_resolve_against_the_file(tmp_path: Path) -> None:
    (tmp_path / "c.json").write_text(json.dumps({"output_dir": "out", "data": {"root": "../d"}}))
    cfg = load_config(tmp_path / "c.json")
    assert cfg.output_dir == tmp_path / "out" and cfg.data.root == tmp_path / "../d"
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "missing.json")


@pytest.mark.parametrize(
    "name",
    [
        "neural-gaffer-paper",
        "tiny-smoke",
        "gaffer-tiny-stage5",
        "gaffer-tiny-wide",
        "gaffer-tiny-stage6",
    ],
)
def test_shipped_configs_load(name: str) -> None:
    cfg = load_config(CONFIGS / f"{name}.json")
    if name == "neural-gaffer-paper":
        assert cfg.model.init == "zero123-xl" and cfg.train.max_steps == 80_000
        assert cfg.train.batch_size * cfg.data.targets_per_sample * 8 == 1024
    if name in ("gaffer-tiny-stage5", "gaffer-tiny-wide", "gaffer-tiny-stage6"):
        # gaffer-tiny 0.6, the wide experiment and stage 6: the one-step sampler trained on its score
        assert cfg.train.loss_space == "display_object" and cfg.train.timestep_range == (999, 999)
        assert cfg.model.init == "pretrained" and cfg.train.residual_loss_floor is None
    if name == "gaffer-tiny-stage6":
        # stage 4's renders plus the two sets lit by the physical maps
        assert [p.name for p in cfg.data.extra_roots] == ["render_train09", "render_train09b"]


def test_object_fraction_defaults_to_the_whole_render_and_is_validated() -> None:
    base = {"output_dir": "r", "data": {"root": "d"}}
    assert TrainConfig.from_dict(base).data.object_fraction is None
    cfg = TrainConfig.from_dict({**base, "data": {"root": "d", "object_fraction": 0.75}})
    assert cfg.data.object_fraction == 0.75
    assert TrainConfig.from_dict(cfg.to_dict()) == cfg
    for bad in (0, 0.0, 1.5, -0.5):
        with pytest.raises(ConfigError, match=r"data\.object_fraction"):
            TrainConfig.from_dict({**base, "data": {"root": "d", "object_fraction": bad}})
