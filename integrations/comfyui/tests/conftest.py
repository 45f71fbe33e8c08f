"""Fixtures of the node pack's tests: the pack loaded as ComfyUI loads a custom-nodes folder (without
ComfyUI), the shipped example photo as ComfyUI's LoadImage reads it, and a small runner of API-format
workflows (`run_workflow`) over our node classes plus stand-ins of the three ComfyUI core nodes the
example workflow uses (LoadImage, SaveImage, PreviewImage), written from ComfyUI's `nodes.py` semantics.
"""

import importlib.util
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any, ClassVar

import numpy as np
import pytest
import torch
from PIL import Image, ImageOps

PACK = Path(__file__).resolve().parent.parent
"""integrations/comfyui: what a user copies into ComfyUI/custom_nodes/."""

PACK_MODULE = "neural_gaffer_nodes"
"""The module name ComfyUI would give the copied folder (it uses the folder's name)."""


def load_pack_like_comfyui(folder: Path = PACK, name: str = PACK_MODULE) -> ModuleType:
    """Import `folder/__init__.py` the way ComfyUI's `load_custom_node` does: a module spec from the
    file, registered in `sys.modules` under the folder's name, then executed."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, folder / "__init__.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def pack() -> ModuleType:
    """The pack's entry module (`NODE_CLASS_MAPPINGS`, `NODE_DISPLAY_NAME_MAPPINGS`)."""
    return load_pack_like_comfyui()


@pytest.fixture(scope="session")
def nodes(pack: ModuleType) -> dict[str, type]:
    return dict(pack.NODE_CLASS_MAPPINGS)


@pytest.fixture(scope="session")
def lib(pack: ModuleType) -> ModuleType:
    """The pack's node package (`src/gaffer_comfyui`) as loaded through the entry module."""
    return sys.modules[f"{PACK_MODULE}.src.gaffer_comfyui"]


def example_photo() -> Path:
    """The shipped example object photo: an RGBA render of a held-out object, 128 x 128."""
    from gaffer_diffusion import pretrained

    return pretrained.example_dataset_path() / "objects" / "procedural_002" / "lit" / "000_000.png"


def comfy_load_image(path: Path) -> tuple[torch.Tensor, torch.Tensor]:
    """ComfyUI's LoadImage on one still picture: IMAGE `[1, H, W, 3]` = RGB / 255, MASK `[1, H, W]`
    = 1 - alpha / 255 (an empty 64 x 64 MASK when the picture has no alpha)."""
    with Image.open(path) as im:
        i = ImageOps.exif_transpose(im)
        rgb = np.array(i.convert("RGB")).astype(np.float32) / 255.0
        if "A" in i.getbands():
            mask = 1.0 - np.array(i.getchannel("A")).astype(np.float32) / 255.0
        else:
            mask = np.zeros((64, 64), np.float32)
    return torch.from_numpy(rgb)[None], torch.from_numpy(mask)[None]


@pytest.fixture(scope="session")
def photo() -> tuple[torch.Tensor, torch.Tensor]:
    """The example photo as LoadImage gives it: (IMAGE, MASK with the object black)."""
    return comfy_load_image(example_photo())


@pytest.fixture(scope="session")
def tiny(nodes: dict[str, type]) -> Any:
    """The shipped gaffer-tiny through the LoadModel node, on the CPU (loaded once)."""
    (model,) = nodes["NeuralGafferLoadModel"]().load("gaffer-tiny", "", "cpu", "float32")
    return model


# ----- a small runner of API-format workflows -----


class LoadImage:
    """Stand-in of ComfyUI's core LoadImage: `image` is a file name in `input_dir`."""

    input_dir: Path = Path(".")
    CATEGORY = "image"
    FUNCTION = "load_image"
    RETURN_TYPES = ("IMAGE", "MASK")

    @classmethod
    def INPUT_TYPES(cls) -> dict[str, Any]:
        return {"required": {"image": (sorted(p.name for p in cls.input_dir.iterdir()),)}}

    def load_image(self, image: str) -> tuple[torch.Tensor, torch.Tensor]:
        return comfy_load_image(self.input_dir / image)


class SaveImage:
    """Stand-in of ComfyUI's core SaveImage: keeps the images (an output node)."""

    CATEGORY = "image"
    FUNCTION = "save_images"
    RETURN_TYPES = ()
    OUTPUT_NODE = True
    saved: ClassVar[list[tuple[str, torch.Tensor]]] = []

    @classmethod
    def INPUT_TYPES(cls) -> dict[str, Any]:
        return {"required": {"images": ("IMAGE",), "filename_prefix": ("STRING", {})}}

    def save_images(self, images: torch.Tensor, filename_prefix: str) -> tuple[()]:
        type(self).saved.append((filename_prefix, images))
        return ()


class PreviewImage(SaveImage):
    """Stand-in of ComfyUI's core PreviewImage."""

    @classmethod
    def INPUT_TYPES(cls) -> dict[str, Any]:
        return {"required": {"images": ("IMAGE",)}}

    def save_images(self, images: torch.Tensor, filename_prefix: str = "preview") -> tuple[()]:
        return super().save_images(images, filename_prefix)


CORE_NODES: dict[str, type] = {
    "LoadImage": LoadImage,
    "SaveImage": SaveImage,
    "PreviewImage": PreviewImage,
}


def _check_widget(where: str, spec: tuple[Any, ...], value: Any) -> None:
    kind, opts = spec[0], (spec[1] if len(spec) > 1 else {})
    if isinstance(kind, list):
        assert value in kind, f"{where}: {value!r} is not one of {kind}"
    elif kind == "INT":
        assert isinstance(value, int) and not isinstance(value, bool), f"{where}: {value!r}"
    elif kind == "FLOAT":
        assert isinstance(value, int | float) and not isinstance(value, bool), f"{where}: {value!r}"
    elif kind == "STRING":
        assert isinstance(value, str), f"{where}: {value!r}"
    elif kind == "BOOLEAN":
        assert isinstance(value, bool), f"{where}: {value!r}"
    else:
        raise AssertionError(f"{where}: a {kind} input must be a link, got {value!r}")
    if kind in ("INT", "FLOAT"):
        assert opts.get("min", -np.inf) <= value <= opts.get("max", np.inf), f"{where}: {value!r}"


def run_workflow(prompt: dict[str, Any], classes: dict[str, type]) -> dict[str, tuple[Any, ...]]:
    """Validate and run an API-format workflow (`{id: {"class_type", "inputs"}}`, links as
    `[id, output_index]`) as ComfyUI's executor does: every required input present, links typed
    (the output's RETURN_TYPES entry equals the input's declared type), widget values within their
    declared choices and ranges; nodes run once each, dependencies first. Returns every node's outputs.
    """
    declared: dict[str, dict[str, tuple[Any, ...]]] = {}
    for node_id, node in prompt.items():
        cls = classes[node["class_type"]]
        types = cls.INPUT_TYPES()
        req, opt = types.get("required", {}), types.get("optional", {})
        declared[node_id] = {**req, **opt}
        missing = set(req) - set(node["inputs"])
        assert not missing, f"node {node_id} ({node['class_type']}) lacks inputs {sorted(missing)}"
        for name, value in node["inputs"].items():
            where = f"node {node_id} ({node['class_type']}) input `{name}`"
            assert name in declared[node_id], f"{where} is not declared"
            if isinstance(value, list) and len(value) == 2 and isinstance(value[0], str):
                src = prompt[value[0]]
                out_type = classes[src["class_type"]].RETURN_TYPES[value[1]]
                assert out_type == declared[node_id][name][0], f"{where}: {out_type} link"
            else:
                _check_widget(where, declared[node_id][name], value)
    results: dict[str, tuple[Any, ...]] = {}

    def run(node_id: str) -> tuple[Any, ...]:
        if node_id not in results:
            node = prompt[node_id]
            cls = classes[node["class_type"]]
            kwargs = {
                name: run(v[0])[v[1]]
                if isinstance(v, list) and len(v) == 2 and isinstance(v[0], str)
                else v
                for name, v in node["inputs"].items()
            }
            results[node_id] = getattr(cls(), cls.FUNCTION)(**kwargs)
        return results[node_id]

    for node_id in prompt:
        run(node_id)
    return results


@pytest.fixture
def workflow_runner(nodes: dict[str, type]) -> Callable[..., Any]:
    """`run(prompt, input_dir)`: `run_workflow` over our nodes and the core stand-ins; returns every
    node's outputs and what the SaveImage / PreviewImage nodes received, as (prefix, IMAGE) pairs."""

    def run(
        prompt: dict[str, Any], input_dir: Path
    ) -> tuple[dict[str, tuple[Any, ...]], list[tuple[str, torch.Tensor]]]:
        LoadImage.input_dir = input_dir
        SaveImage.saved.clear()
        results = run_workflow(prompt, {**CORE_NODES, **nodes})
        return results, list(SaveImage.saved)

    return run


@pytest.fixture(scope="session")
def photo_path() -> Path:
    """The shipped example object photo (RGBA, 128 x 128)."""
    return example_photo()


@pytest.fixture(scope="session")
def load_image() -> Callable[[Path], tuple[torch.Tensor, torch.Tensor]]:
    """ComfyUI's LoadImage semantics on a file (`comfy_load_image`)."""
    return comfy_load_image
