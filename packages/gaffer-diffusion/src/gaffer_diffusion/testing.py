"""Public test helpers: tiny random models, random conditions and fake checkpoint folders.

Sibling packages and e2e tests import these (tests run with `--import-mode=importlib`). Nothing here
downloads anything: every model is a random-initialised `tiny` preset, and the rendered dataset is
written without Blender.
"""

import dataclasses
import json
import math
import pickle
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import save_file

from gaffer_diffusion.conditioning import LightingMaps, RelightingConditions
from gaffer_diffusion.configs import ModelConfig, get_preset
from gaffer_diffusion.models.build import build_model, build_unet
from gaffer_diffusion.models.model import NeuralGafferModel


def tiny_model(seed: int = 0) -> NeuralGafferModel:
    """The `tiny` preset with random weights (float32, CPU, eval mode)."""
    return build_model(get_preset("tiny"), seed=seed)


def random_conditions(
    batch_size: int = 1, resolution: int = 64, *, seed: int = 0
) -> RelightingConditions:
    """Random `[B, 3, R, R]` image and lighting maps in [0, 1] standing in for real inputs."""
    g = torch.Generator().manual_seed(seed)
    shape = (batch_size, 3, resolution, resolution)
    return RelightingConditions(
        image=torch.rand(shape, generator=g),
        lighting=LightingMaps(
            ldr=torch.rand(shape, generator=g), hdr=torch.rand(shape, generator=g)
        ),
    )


def write_fake_zero123(
    model: NeuralGafferModel, directory: Path, *, unet_in_channels: int = 8, seed: int = 1
) -> Path:
    """A fake Zero-1-to-3 XL diffusers folder holding `model`'s VAE and CLIP encoder.

    Its UNet has `model`'s shapes but `unet_in_channels` inputs (Zero123: 8) and its own random weights,
    like the real base model whose UNet the released checkpoint replaces.
    """
    directory.mkdir(parents=True, exist_ok=True)
    cfg = dataclasses.replace(model.config.unet, in_channels=unet_in_channels)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        unet = build_unet(cfg)
    unet.save_pretrained(directory / "unet", safe_serialization=True)
    model.vae.save_pretrained(directory / "vae", safe_serialization=True)
    model.image_encoder.save_pretrained(directory / "image_encoder", safe_serialization=True)
    (directory / "scheduler").mkdir(exist_ok=True)
    sched = {"_class_name": "DDIMScheduler", **dataclasses.asdict(model.config.scheduler)}
    (directory / "scheduler" / "scheduler_config.json").write_text(json.dumps(sched))
    # Zero123's pose projection (CLIP embedding + 4 pose numbers -> embedding): the real base ships it
    # and lists it in model_index.json; Neural Gaffer drops it, so nothing may read it
    d = model.config.unet.cross_attention_dim
    (directory / "cc_projection").mkdir(exist_ok=True)
    (directory / "cc_projection" / "config.json").write_text(
        json.dumps({"_class_name": "CCProjection", "in_channel": d + 4, "out_channel": d})
    )
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed + 1)
        proj = {"projection.weight": torch.randn(d, d + 4), "projection.bias": torch.zeros(d)}
    save_file(proj, str(directory / "cc_projection" / "diffusion_pytorch_model.safetensors"))
    (directory / "model_index.json").write_text(
        json.dumps(
            {
                "_class_name": "Zero1to3StableDiffusionPipeline",
                "_diffusers_version": "0.18.0",
                "cc_projection": ["pipeline_zero1to3", "CCProjection"],
                "feature_extractor": ["transformers", "CLIPImageProcessor"],
                "image_encoder": ["transformers", "CLIPVisionModelWithProjection"],
                "scheduler": ["diffusers", "DDIMScheduler"],
                "unet": ["diffusers", "UNet2DConditionModel"],
                "vae": ["diffusers", "AutoencoderKL"],
            },
            indent=2,
        )
    )
    return directory


def write_fake_authors_checkpoint(
    model: NeuralGafferModel, directory: Path, *, file_format: str = "safetensors"
) -> Path:
    """A fake `checkpoint-80000/` folder laid out as accelerate's save-state in the release.

    `model`'s UNet state dict (plain diffusers keys) as `model.safetensors` or `pytorch_model.bin`,
    plus the training state that sits beside it and must be ignored: `optimizer.bin`,
    `scheduler.bin`, `scaler.pt` (small torch files) and `random_states_0.pkl` (a pickle that nothing
    may unpickle).

    Args:
        model: whose UNet to save.
        directory: the folder to create (name it `checkpoint-80000` to mirror the release).
        file_format: "safetensors" (`model.safetensors`) or "bin" (`pytorch_model.bin`).
    """
    directory.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().clone().contiguous() for k, v in model.unet.state_dict().items()}
    if file_format == "safetensors":
        save_file(state, str(directory / "model.safetensors"))
    else:
        torch.save(state, directory / "pytorch_model.bin")
    torch.save(
        {"state": {}, "param_groups": [{"lr": 1e-4, "params": []}]}, directory / "optimizer.bin"
    )
    torch.save({"last_epoch": 80000, "_step_count": 80001}, directory / "scheduler.bin")
    torch.save(
        {"scale": 65536.0, "growth_factor": 2.0, "_growth_tracker": 0}, directory / "scaler.pt"
    )
    (directory / "random_states_0.pkl").write_bytes(pickle.dumps({"step": 80000, "python": None}))
    return directory


def tiny_config() -> ModelConfig:
    """The `tiny` preset config."""
    return get_preset("tiny")


def write_tiny_render_dataset(
    root: Path, *, lightings: int = 3, resolution: int = 32, views: int = 1
) -> Path:
    """A gaffer-data render folder written without Blender: one object ("disc"), flat-shaded PNGs.

    Each view has `lightings` renders under two tiny 8 x 16 env maps ("warm", "cool", written to
    `root/envmaps`; every third draw is mirrored and yawed), an alpha mask and its camera pose; the
    object's manifest goes through gaffer-data's schema, so `gaffer_data.open_dataset` reads it. The
    disc's colour changes with the lighting, so relighting has something to score.

    Needs gaffer-data and gaffer-envmap (imported here, not at module import); the folder is written by
    gaffer-data's own fake-dataset writer, `gaffer_data.testing.write_fake_object`.

    Returns:
        `root`, the dataset folder (`root/objects/disc/`).
    """
    from gaffer_data.dataset import (
        CameraSample,
        EnvmapRef,
        Intrinsics,
        LitImage,
        ObjectPlan,
        ViewRecord,
        sha256_file,
    )
    from gaffer_data.testing import tiny_config, write_fake_object
    from gaffer_envmap import EnvironmentMap, write_envmap
    from gaffer_envmap.poses import orbit_w2c_blender

    res = resolution
    envmaps = {}
    (root / "envmaps").mkdir(parents=True, exist_ok=True)
    for k, (name, rgb) in enumerate({"warm": (1.0, 0.6, 0.3), "cool": (0.2, 0.4, 1.0)}.items()):
        env = np.broadcast_to(np.asarray(rgb, np.float32), (8, 16, 3)).copy()
        env[2, 3 + 5 * k] = 50.0  # a small sun, at a different place per map
        envmaps[name] = root / "envmaps" / f"{name}.exr"
        write_envmap(envmaps[name], EnvironmentMap(radiance_linear=env))
    obj = root / "objects" / "disc"
    (obj / "lit").mkdir(parents=True)
    (obj / "alpha").mkdir()
    yy, xx = np.mgrid[:res, :res]
    alpha = (((yy - res / 2) ** 2 + (xx - res / 2) ** 2) < (res / 3) ** 2).astype(np.uint8) * 255
    names = list(envmaps)
    view_records, w2c = [], []
    pngs: dict[str, np.ndarray] = {}
    for v in range(views):
        az, el = 40.0 * v, 15.0
        w2c.append(orbit_w2c_blender(az, el, 2.0).matrix)
        lit = []
        for li in range(lightings):
            name = names[li % len(names)]
            ref = EnvmapRef(
                name=name,
                source=str(envmaps[name]),
                source_sha256=sha256_file(envmaps[name]),
                flip=li % 3 == 2,
                yaw_step=li % 4,
                num_steps=4,
            )
            rgba = np.zeros((res, res, 4), np.uint8)
            rgba[..., :3] = (np.array([60, 120, 200]) + 40 * li + 10 * v) % 256
            rgba[..., 3] = alpha
            png = f"lit/{v:03d}_{li:03d}.png"
            pngs[png] = rgba
            lit.append(LitImage(lighting_index=li, envmap=ref, exr=png, png=png))
        pngs[f"alpha/{v:03d}.png"] = alpha
        cam = CameraSample(elevation_deg=el, azimuth_deg=az, distance=2.0, position=(0.0, 0.0, 0.0))
        view_records.append(
            ViewRecord(index=v, camera=cam, lit=tuple(lit), area=None, alpha=f"alpha/{v:03d}.png")
        )
    w2c_arr = np.stack(w2c)
    c2w_cv = np.stack([np.linalg.inv(np.vstack([m, [0, 0, 0, 1]])) for m in w2c_arr])
    c2w_cv = c2w_cv @ np.diag([1.0, -1.0, -1.0, 1.0])
    plan = ObjectPlan(
        object_id="disc",
        source="disc.obj",
        views=tuple(view_records),
        intrinsics=Intrinsics(width=res, height=res, fx=35.0, fy=35.0, cx=res / 2, cy=res / 2),
        config=tiny_config(views=views, lightings=lightings, resolution=res),
    )
    write_fake_object(
        obj,
        plan,
        pngs=pngs,
        w2c_blender=w2c_arr,
        c2w_opencv=c2w_cv,
        intrinsics=np.array([[35.0, 0, res / 2], [0, 35.0, res / 2], [0, 0, 1]]),
    )
    return root


def _pil_like_kernel(name: str) -> tuple[float, Any]:
    """(support, kernel) of a resampling filter, from its textbook formula."""
    if name == "lanczos":

        def lanczos(x: np.ndarray) -> np.ndarray:
            return np.where(np.abs(x) < 3.0, np.sinc(x) * np.sinc(x / 3.0), 0.0)

        return 3.0, lanczos

    def bicubic(x: np.ndarray, a: float = -0.5) -> np.ndarray:  # Keys' cubic, a = -0.5
        x = np.abs(x)
        near = ((a + 2) * x - (a + 3)) * x * x + 1
        far = ((a * x - 5 * a) * x + 8 * a) * x - 4 * a
        return np.where(x < 1, near, np.where(x < 2, far, 0.0))

    return 2.0, bicubic


def _resample_axis(img: np.ndarray, out_len: int, axis: int, kernel: str) -> np.ndarray:
    """Antialiased convolution resampling of float `img` along `axis` (kernel widened by the scale when
    shrinking; taps at the input pixel centres inside the image, weights normalised to sum 1)."""
    support, k = _pil_like_kernel(kernel)
    n_in = img.shape[axis]
    scale = n_in / out_len
    widen = max(scale, 1.0)
    out = np.empty((*img.shape[:axis], out_len, *img.shape[axis + 1 :]), np.float64)
    moved_in, moved_out = np.moveaxis(img, axis, 0), np.moveaxis(out, axis, 0)
    for i in range(out_len):
        centre = (i + 0.5) * scale
        lo = max(int(centre - support * widen + 0.5), 0)
        hi = min(int(centre + support * widen + 0.5), n_in)
        taps = np.arange(lo, hi)
        w = k((taps - centre + 0.5) / widen)
        w = w / w.sum()
        moved_out[i] = np.tensordot(w, moved_in[lo:hi], axes=(0, 0))
    return out


def _resize_u8(img_u8: np.ndarray, width: int, height: int, kernel: str) -> np.ndarray:
    """8-bit resize: horizontal pass, stored as 8 bit, then vertical pass, stored as 8 bit."""
    x = img_u8.astype(np.float64)
    for axis, n in ((1, width), (0, height)):
        if x.shape[axis] != n:
            x = np.clip(np.floor(_resample_axis(x, n, axis, kernel) + 0.5), 0, 255)
    return x.astype(np.uint8)


def _fit_inside(width: int, height: int, limit: int) -> tuple[int, int]:
    """Size of a `thumbnail` to `limit` x `limit`: the aspect kept, the integer side nearest to it."""
    if width <= limit and height <= limit:
        return width, height
    if width >= height:
        exact = height * limit / width
        cands = {max(math.floor(exact), 1), max(math.ceil(exact), 1)}
        return limit, min(cands, key=lambda n: abs(width / height - limit / n))
    exact = width * limit / height
    cands = {max(math.floor(exact), 1), max(math.ceil(exact), 1)}
    return min(cands, key=lambda n: abs(width / height - n / limit)), limit


def reference_prepare_neural_gaffer(
    rgb: np.ndarray,
    alpha: np.ndarray,
    size: int = 256,
    *,
    resample: str = "lanczos",
    alpha_threshold: int = 0,
    side_rounding: str = "floor",
    placement: str = "half-minus-half",
    composite: str = "after-resize",
    quantize: str = "truncate",
) -> np.ndarray:
    """The authors' real-image preparation (our reading of their script) from its description, in
    numpy.

    Shares no code with `gaffer_diffusion.preprocess`: the resampling filters are written from their
    formulas (Lanczos-3 / Keys cubic, widened by the scale when shrinking, 8-bit storage after each
    pass), premultiplied alpha by hand. Inputs up to 2047 px: PIL's `thumbnail` box-reduces first
    when it shrinks 4x or more, which this does not model.

    The keyword arguments switch single steps to the readings our old code made, so
    tests can show each reading matters: `resample="bicubic"`, `alpha_threshold=127` (alpha > 0.5),
    `side_rounding="ceil"`, `placement="centred-remainder"` ((side - h) // 2),
    `composite="before-resize"`, `quantize="round"`.

    Args:
        rgb: `[H, W, 3]` uint8.
        alpha: `[H, W]` uint8 (SAM's mask in their script).
        size: output side.

    Returns:
        `[size, size, 3]` uint8 on white.
    """
    h0, w0 = alpha.shape
    tw, th = _fit_inside(w0, h0, 512)
    photo = _resize_u8(rgb, tw, th, "lanczos")
    mask = _resize_u8(alpha[..., None], tw, th, "lanczos")[..., 0]
    rows = np.flatnonzero((mask > alpha_threshold).any(axis=1))
    cols = np.flatnonzero((mask > alpha_threshold).any(axis=0))
    top, bottom, left, right = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    h, w = bottom - top, right - left
    longest = max(h, w) / 0.75
    side = math.ceil(longest) if side_rounding == "ceil" else math.floor(longest)
    if placement == "centred-remainder":
        r0, c0 = (side - h) // 2, (side - w) // 2
    else:
        r0, c0 = side // 2 - h // 2, side // 2 - w // 2
    canvas = np.zeros((side, side, 4), np.float64)
    canvas[r0 : r0 + h, c0 : c0 + w, :3] = photo[top:bottom, left:right]
    canvas[r0 : r0 + h, c0 : c0 + w, 3] = mask[top:bottom, left:right]
    a = canvas[..., 3:] / 255.0
    if composite == "before-resize":
        white = np.round((canvas[..., :3] / 255.0 * a + (1 - a)) * 255).astype(np.uint8)
        small = _resize_u8(white, size, size, resample).astype(np.float64) / 255.0
    else:
        premult = np.floor(canvas[..., :3] * a + 0.5).astype(np.uint8)
        pm_small = _resize_u8(premult, size, size, resample).astype(np.float64)
        a_small = _resize_u8(canvas[..., 3:].astype(np.uint8), size, size, resample)
        a_small = a_small.astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            straight = np.where(a_small > 0, np.clip(pm_small * 255 / a_small, 0, 255), 0)
        straight = np.floor(straight) / 255.0
        af = a_small / 255.0
        small = straight * af + (1 - af)
    v = small * 255
    return (np.floor(v + 0.5) if quantize == "round" else np.floor(v)).clip(0, 255).astype(np.uint8)
