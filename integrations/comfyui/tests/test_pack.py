"""The pack imports without ComfyUI (both ways a user installs it) and every node's declarations agree
with the function ComfyUI will call (the checks ComfyUI's loader and executor rely on)."""

import inspect
import json
import subprocess
import sys
import textwrap
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

PACK = Path(__file__).resolve().parent.parent
NODE_IDS = (
    "NeuralGafferLoadModel",
    "NeuralGafferLoadEnvmap",
    "NeuralGafferRotateEnvmap",
    "NeuralGafferSky",
    "NeuralGafferRelight",
    "NeuralGafferTurntable",
    "NeuralGafferInsert",
)
COMFY_TYPES = {
    "IMAGE",
    "MASK",
    "INT",
    "FLOAT",
    "STRING",
    "BOOLEAN",
    "GAFFER_MODEL",
    "GAFFER_ENVMAP",
}


def test_imports_without_comfyui_both_ways() -> None:
    """In a fresh interpreter where `comfy`, `folder_paths` and `nodes` cannot be imported: the folder
    loads as ComfyUI loads a custom-nodes folder, and `gaffer_comfyui` imports as pip installs it;
    neither touches a ComfyUI module."""
    script = textwrap.dedent(
        f"""
        import importlib.abc, importlib.util, sys
        BLOCKED = ("comfy", "folder_paths", "nodes", "comfy_extras", "server")

        class Block(importlib.abc.MetaPathFinder):
            def find_spec(self, name, path=None, target=None):
                if name.split(".")[0] in BLOCKED:
                    raise ImportError(f"{{name}} is ComfyUI's (blocked in this test)")
                return None

        sys.meta_path.insert(0, Block())
        spec = importlib.util.spec_from_file_location("neural-gaffer", {str(PACK / "__init__.py")!r})
        mod = importlib.util.module_from_spec(spec)
        sys.modules["neural-gaffer"] = mod
        spec.loader.exec_module(mod)
        sys.path.insert(0, {str(PACK / "src")!r})
        import gaffer_comfyui
        assert sorted(gaffer_comfyui.NODE_CLASS_MAPPINGS) == sorted(mod.NODE_CLASS_MAPPINGS)
        for cls in mod.NODE_CLASS_MAPPINGS.values():
            cls.INPUT_TYPES()
        touched = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)
        assert not touched, touched
        print(",".join(sorted(mod.NODE_CLASS_MAPPINGS)))
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=False
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip().split(",") == sorted(NODE_IDS)


def test_mappings_prefixed_and_named(pack: ModuleType) -> None:
    assert set(pack.NODE_CLASS_MAPPINGS) == set(NODE_IDS)
    assert set(pack.NODE_DISPLAY_NAME_MAPPINGS) == set(NODE_IDS)
    for node_id, cls in pack.NODE_CLASS_MAPPINGS.items():
        assert node_id.startswith("NeuralGaffer") and cls.__name__ == node_id
        assert pack.NODE_DISPLAY_NAME_MAPPINGS[node_id].startswith("Neural Gaffer: ")


def _widget_ok(spec: tuple[Any, ...]) -> None:
    kind, opts = spec[0], (spec[1] if len(spec) > 1 else {})
    assert isinstance(opts, dict)
    if isinstance(kind, list):
        assert kind and all(isinstance(c, str) for c in kind)
        assert opts.get("default", kind[0]) in kind
        return
    assert kind in COMFY_TYPES, kind
    if "default" in opts and kind in ("INT", "FLOAT"):
        assert opts.get("min", -float("inf")) <= opts["default"] <= opts.get("max", float("inf"))
        assert isinstance(opts["default"], int if kind == "INT" else float | int)
    if "default" in opts and kind == "STRING":
        assert isinstance(opts["default"], str)


@pytest.mark.parametrize("node_id", NODE_IDS)
def test_declarations_match_the_function(nodes: dict[str, type], node_id: str) -> None:
    """INPUT_TYPES / RETURN_TYPES / RETURN_NAMES / FUNCTION / CATEGORY agree with the method: every
    required input is a parameter without a default, every optional one a parameter with one, and
    nothing else; the output types are known ComfyUI types or ours."""
    cls = nodes[node_id]
    types = cls.INPUT_TYPES()
    assert set(types) <= {"required", "optional", "hidden"}
    required, optional = types.get("required", {}), types.get("optional", {})
    for spec in (*required.values(), *optional.values()):
        assert isinstance(spec, tuple) and 1 <= len(spec) <= 2
        _widget_ok(spec)
    assert isinstance(cls.CATEGORY, str) and cls.CATEGORY == "Neural Gaffer"
    assert isinstance(cls.RETURN_TYPES, tuple) and cls.RETURN_TYPES
    assert all(t in COMFY_TYPES for t in cls.RETURN_TYPES)
    assert len(cls.RETURN_NAMES) == len(cls.RETURN_TYPES)
    assert isinstance(cls.DESCRIPTION, str) and cls.DESCRIPTION
    fn = getattr(cls, cls.FUNCTION)
    params = dict(inspect.signature(fn).parameters)
    params.pop("self")
    assert set(params) == set(required) | set(optional)
    for name in required:
        assert params[name].default is inspect.Parameter.empty, name
    for name in optional:
        assert params[name].default is not inspect.Parameter.empty, name


def test_custom_types_are_frozen_dataclasses(lib: ModuleType) -> None:
    import dataclasses

    for cls in (lib.GafferModel, lib.GafferEnvmap):
        assert dataclasses.is_dataclass(cls) and cls.__dataclass_params__.frozen


def test_example_workflow_uses_only_our_nodes_and_core_ones(nodes: dict[str, type]) -> None:
    prompt = json.loads((PACK / "workflows" / "relight.json").read_text())
    kinds = {n["class_type"] for n in prompt.values()}
    assert kinds - set(nodes) == {"LoadImage", "SaveImage", "PreviewImage"}


def test_registry_metadata() -> None:
    import tomllib

    meta = tomllib.loads((PACK / "pyproject.toml").read_text())
    assert "ComfyUI" not in meta["project"]["name"]  # the registry's naming rule
    assert {"PublisherId", "DisplayName", "Icon"} <= set(meta["tool"]["comfy"])
    assert any(d.startswith("gaffer-diffusion") for d in meta["project"]["dependencies"])
    version = {}
    exec((PACK / "src" / "gaffer_comfyui" / "_version.py").read_text(), version)
    assert len(version["__version__"].split(".")) == 3  # X.Y.Z, as the registry asks
