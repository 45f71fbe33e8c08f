"""gaffer-tiny: validation quality over the object mask against CPU training time, per resolution.

Not a timed benchmark (it needs the renders and training runs of the model card): it reads what those
runs wrote and charts it, so the resolution / training-time choice of the shipped model is shown, not
asserted. Inputs, per run: its `logs/train.jsonl` (training time = the sum over logging intervals of
steps x batch / samples_per_s) and one `gaffer-diffusion evaluate --json` file per exported checkpoint
on the validation split.

Run:
    python benchmarks/plot_gaffer_tiny_training.py --run 128=RUN128 --run 64=RUN64 \\
        --eval 128:300=val_300.json ... --eval 64:400=val64_400.json ... --out benchmarks/results

Writes `gaffer_tiny_training.json` and `gaffer_tiny_training.png`.
"""

import argparse
import json
from pathlib import Path
from typing import Any


def training_seconds(log: Path, batch_size: int) -> dict[int, float]:
    """Cumulative training seconds at each logged step (from the logged throughput)."""
    out: dict[int, float] = {}
    total, last = 0.0, 0
    for line in log.read_text().splitlines():
        row = json.loads(line)
        if row.get("kind") != "train" or not row.get("samples_per_s"):
            continue
        step = int(row["step"])
        total += (step - last) * batch_size / float(row["samples_per_s"])
        out[step], last = total, step
    return out


def _at(seconds: dict[int, float], step: int) -> float:
    known = [s for s in seconds if s <= step]
    return seconds[max(known)] if known else 0.0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--run", action="append", required=True, help="RES=RUN_DIR")
    p.add_argument("--eval", action="append", required=True, help="RES:STEP=EVAL.json")
    p.add_argument("--batch-size", type=int, default=8)
    p.add_argument("--out", type=Path, default=Path("benchmarks/results"))
    args = p.parse_args(argv)
    runs = {int(k): Path(v) for k, v in (r.split("=", 1) for r in args.run)}
    seconds = {
        res: training_seconds(d / "logs" / "train.jsonl", args.batch_size)
        for res, d in runs.items()
    }
    rows: list[dict[str, Any]] = []
    for spec in args.eval:
        key, path = spec.split("=", 1)
        res, step = (int(x) for x in key.split(":"))
        d = json.loads(Path(path).read_text())
        m, b = d["metrics"], d["baseline_unrelit_input"]
        rows.append(
            {
                "resolution": res,
                "step": step,
                "train_seconds": round(_at(seconds[res], step), 1),
                "object_psnr": m["mean_object_raw"]["psnr"],
                "object_psnr_aligned": m["mean_object_aligned"]["psnr"],
                "input_object_psnr": b["mean_object_raw"]["psnr"],
                "input_object_psnr_aligned": b["mean_object_aligned"]["psnr"],
                "closer_than_input": d["closer_than_input"],
                "pairs": len(m["items"]),
                "eval": str(path),
            }
        )
    rows.sort(key=lambda r: (r["resolution"], r["step"]))
    args.out.mkdir(parents=True, exist_ok=True)
    payload = {
        "benchmark": "gaffer_tiny_training",
        "what": "validation split (objects and HDRIs apart from train and test), object mask, "
        "1 DDIM step + mirror mean, each resolution scored at its own size against renders "
        "resized to it (so compare gains over the unrelit input, not absolute dB across sizes)",
        "rows": rows,
    }
    (args.out / "gaffer_tiny_training.json").write_text(json.dumps(payload, indent=2) + "\n")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, key, base, label in (
        (axes[0], "object_psnr", "input_object_psnr", "gain in object PSNR over the input (dB)"),
        (
            axes[1],
            "object_psnr_aligned",
            "input_object_psnr_aligned",
            "gain in aligned object PSNR (dB)",
        ),
    ):
        for res in sorted({r["resolution"] for r in rows}):
            rs = [r for r in rows if r["resolution"] == res]
            x = [r["train_seconds"] / 60 for r in rs]
            y = [r[key] - r[base] for r in rs]
            ax.plot(x, y, "o-", label=f"{res} px")
            for r, xi, yi in zip(rs, x, y, strict=True):
                ax.annotate(str(r["step"]), (xi, yi), fontsize=7)
        ax.axhline(0.0, color="gray", ls="--", lw=0.8)
        ax.set_xlabel("training time on 2 CPU cores (minutes; labels = steps)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle("gaffer-tiny 0.3: validation quality over the object mask vs training time")
    fig.tight_layout()
    fig.savefig(args.out / "gaffer_tiny_training.png", dpi=110)
    print(f"wrote {args.out / 'gaffer_tiny_training.json'} and .png ({len(rows)} points)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
