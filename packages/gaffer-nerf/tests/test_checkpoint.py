"""The checkpoint header (`config.json`'s `_class_name` / `format_version`), checked by the shared
`gaffer_envmap.schema_header` helper: same MAJOR read whatever its MINOR, another MAJOR refused."""

import json
from pathlib import Path

import pytest
import torch

from gaffer_nerf.checkpoint import CONFIG_NAME, FORMAT_VERSION, load_field, save_field
from gaffer_nerf.configs import SceneBoxConfig, TensoRFConfig
from gaffer_nerf.errors import CheckpointError
from gaffer_nerf.fields import TensoRFVM

CFG = TensoRFConfig(
    density_ranks=(2, 3, 2), appearance_ranks=(3, 2, 4), appearance_dim=5, mlp_hidden=8
)
SCENE = SceneBoxConfig(aabb_min=(-1.0, -1.0, -1.0), aabb_max=(1.0, 1.0, 1.0))


def _saved(folder: Path, **header: object) -> tuple[TensoRFVM, Path]:
    field = TensoRFVM(CFG, SCENE, (5, 6, 7), generator=torch.Generator().manual_seed(0))
    save_field(field, folder)
    cfg = folder / CONFIG_NAME
    meta = json.loads(cfg.read_text())
    for key, value in header.items():
        if value is None:
            meta.pop(key)
        else:
            meta[key] = value
    cfg.write_text(json.dumps(meta))
    return field, folder


@pytest.mark.parametrize("version", [FORMAT_VERSION, "1.7"])
def test_a_supported_format_version_is_read(tmp_path: Path, version: str) -> None:
    field, folder = _saved(tmp_path / "f", format_version=version)
    back = load_field(folder)
    assert back.grid_size == field.grid_size
    for name, value in field.state_dict().items():
        torch.testing.assert_close(back.state_dict()[name], value)


@pytest.mark.parametrize("version", ["2.0", "0.9", None])
def test_an_unsupported_major_format_version_is_refused(
    tmp_path: Path, version: str | None
) -> None:
    _, folder = _saved(tmp_path / "f", format_version=version)
    with pytest.raises(CheckpointError, match=r"has format version .*this gaffer-nerf reads 1\.x"):
        load_field(folder)


def test_another_class_is_refused_first(tmp_path: Path) -> None:
    _, folder = _saved(tmp_path / "f", _class_name="Other", format_version="2.0")
    with pytest.raises(CheckpointError, match=r"`_class_name`='Other', expected 'TensoRFVM'"):
        load_field(folder)


def test_a_failed_save_leaves_the_earlier_field_and_report(tmp_path: Path, monkeypatch) -> None:
    """Weights, config and report are one set, moved in together or not at all."""
    import gaffer_nerf.checkpoint as checkpoint

    field, folder = _saved(tmp_path / "f")
    (folder / "fit_report.json").write_text("{}")
    before = {p.name: p.read_bytes() for p in folder.iterdir()}

    def half_then_fail(state, path):
        Path(path).write_bytes(b"half a file")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(checkpoint, "save_file", half_then_fail)
    with pytest.raises(OSError):
        save_field(field, folder, extra={"fit_report.json": '{"new": 1}'})
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    monkeypatch.undo()
    save_field(field, folder, extra={"fit_report.json": '{"new": 1}'})
    assert json.loads((folder / "fit_report.json").read_text()) == {"new": 1}
    assert sorted(p.name for p in folder.iterdir()) == [
        CONFIG_NAME,
        "field.safetensors",
        "fit_report.json",
    ]
