"""Writing the images: every PNG, the overview sheet and the turntable GIF, each atomically
(`gaffer_envmap.writers`, the one writer and rounding rule of gaffer)."""

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from torch import Tensor

from gaffer_diffusion.demo.config import DemoConfig
from gaffer_diffusion.demo.example import _Example
from gaffer_diffusion.demo.lightings import _Lighting
from gaffer_diffusion.demo.turntable import _side_by_side
from gaffer_diffusion.images import to_uint8 as _uint8
from gaffer_envmap.writers import write_gif, write_png


def _write_png(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_png(path, rgb)


def _write_text(path: Path, text: str) -> None:
    from gaffer_envmap.atomic import atomic_path

    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _write_images(
    out: Path, example: _Example, jobs: Sequence[_Lighting], relit: Tensor, config: DemoConfig
) -> dict[str, Any]:
    """Every PNG, the overview sheet and the GIF; returns relative paths per job key."""
    from gaffer_envmap.preview import contact_sheet

    files: dict[str, Any] = {}
    input_png = "inputs/input.png"
    input_u8 = _uint8(example.input_rgb[0])
    _write_png(out / input_png, input_u8)
    sheet: list[list[tuple[str, np.ndarray]]] = []
    frames: list[np.ndarray] = []
    frame_pngs: list[str] = []
    for k, job in enumerate(jobs):
        relit_u8 = _uint8(relit[k])
        ldr_u8, hdr_u8 = _uint8(job.maps.ldr[0]), _uint8(job.maps.hdr[0])
        if job.kind == "turntable":
            rel = f"turntable/{job.key}.png"
            _write_png(out / rel, relit_u8)
            frame_pngs.append(rel)
            frames.append(_side_by_side(ldr_u8, relit_u8))
            continue
        entry = {
            "input": input_png,
            "world": f"lighting/{job.key}_world.png",
            "ldr": f"lighting/{job.key}_ldr.png",
            "hdr": f"lighting/{job.key}_hdr.png",
            "relit": f"relit/{job.key}.png",
        }
        if job.world_rgb is not None:
            _write_png(out / entry["world"], job.world_rgb)
        _write_png(out / entry["ldr"], ldr_u8)
        _write_png(out / entry["hdr"], hdr_u8)
        _write_png(out / entry["relit"], relit_u8)
        row: list[tuple[str, np.ndarray | None]] = [("", job.world_rgb), ("E_L", ldr_u8)]
        row.append(("E_H", hdr_u8))
        row += [("input", input_u8), ("relit", relit_u8)]
        if job.kind == "target":
            entry["ground_truth"] = f"ground_truth/{job.key}.png"
            gt_u8 = _uint8(example.targets[k])
            _write_png(out / entry["ground_truth"], gt_u8)
            row.append(("ground truth", gt_u8))
        row[0] = (job.label if job.kind == "target" else f"{job.label} (no render)", job.world_rgb)
        sheet.append([(label, im) for label, im in row if im is not None])
        files[job.key] = entry
    _write_png(out / "overview.png", contact_sheet(sheet, cell=128))
    files["turntable"] = {"gif": None, "frames": frame_pngs}
    if frames:
        write_gif(out / "turntable.gif", frames, fps=config.fps)
        files["turntable"]["gif"] = "turntable.gif"
    return files
