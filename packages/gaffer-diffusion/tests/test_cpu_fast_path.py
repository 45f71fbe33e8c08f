"""The CPU fast path: `--dtype auto` (bf16 on a CPU with native bf16, float32 elsewhere), the bf16 path's agreement
with float32, the multistep samplers and their refusals, and the photo encoded once per photo."""

import dataclasses
from pathlib import Path

import pytest
import torch

from gaffer_diffusion import RelightPipeline, RuntimeConfig, SamplingConfig, build_model, get_preset
from gaffer_diffusion import runtime_dtype as rd
from gaffer_diffusion.cli import _parser, _runtime
from gaffer_diffusion.conditioning import LightingMaps, RelightingConditions, encode_conditions
from gaffer_diffusion.errors import ConfigError
from gaffer_diffusion.photo_encoding import PhotoEncodingCache
from gaffer_diffusion.schedulers import make_scheduler
from gaffer_diffusion.testing import random_conditions

AMX = rd.CpuBf16Support(flags=("amx_bf16",), capability="AVX512")
AVX2 = rd.CpuBf16Support(flags=(), capability="AVX2")


def _cpuinfo(tmp_path: Path, flags: str) -> Path:
    path = tmp_path / "cpuinfo"
    path.write_text(
        f"processor\t: 0\nmodel name\t: Test CPU\nflags\t\t: {flags}\n\nprocessor\t: 1\n"
    )
    return path


def test_flags_are_read_from_cpuinfo(tmp_path: Path) -> None:
    assert rd.cpu_flags(_cpuinfo(tmp_path, "fpu avx2 amx_bf16 amx_tile")) >= {"amx_bf16", "avx2"}
    assert rd.cpu_flags(tmp_path / "missing") == frozenset()


@pytest.mark.parametrize(
    ("flags", "capability", "env", "native"),
    [
        ("avx2 avx512f amx_bf16 avx512_bf16", "AVX512", {}, True),
        ("avx2 avx512f avx512_bf16", "AVX512", {}, True),
        ("avx2 avx512f", "AVX512", {}, False),  # AVX-512 without its bf16 extension
        ("avx2 fma", "AVX2", {}, False),
        ("avx2 amx_bf16", "AVX2", {}, False),  # torch runs AVX2 kernels (ATEN_CPU_CAPABILITY)
        ("amx_bf16", "AVX512", {"ONEDNN_MAX_CPU_ISA": "AVX2"}, False),
        ("amx_bf16", "AVX512", {"ONEDNN_MAX_CPU_ISA": "AVX512_CORE_AMX"}, True),
    ],
)
def test_auto_follows_the_cpu(
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
    flags: str,
    capability: str,
    env: dict[str, str],
    native: bool,
) -> None:
    info = _cpuinfo(tmp_path, flags)
    read = rd.cpu_flags
    monkeypatch.setattr(rd, "cpu_flags", lambda cpuinfo=info: read(cpuinfo))
    monkeypatch.setattr(torch.backends.cpu, "get_cpu_capability", lambda: capability)
    for var in ("ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA"):
        monkeypatch.delenv(var, raising=False)
    for var, value in env.items():
        monkeypatch.setenv(var, value)
    choice = rd.resolve_dtype("auto", "cpu", unet_params=860_000_000)
    assert choice.dtype == ("bfloat16" if native else "float32")
    assert choice.reason.startswith("auto: ")
    if "ONEDNN_MAX_CPU_ISA" in env and not native:
        assert "ONEDNN_MAX_CPU_ISA=AVX2" in choice.reason


def test_auto_keeps_small_models_gpus_and_explicit_dtypes() -> None:
    small = rd.resolve_dtype("auto", "cpu", unet_params=3_800_000, support=AMX)
    assert small.dtype == "float32" and "small model" in small.reason
    assert rd.resolve_dtype("auto", "cuda:0", support=AMX).dtype == "float32"
    assert rd.resolve_dtype("float32", "cpu", support=AMX).reason == "--dtype float32"
    slow = rd.resolve_dtype("bfloat16", "cpu", support=AVX2)
    assert slow.dtype == "bfloat16" and "emulated" in slow.reason
    assert rd.resolve_dtype("bfloat16", "cpu", support=AMX).note() == (
        "precision: bfloat16 (--dtype bfloat16)"
    )
    with pytest.raises(ConfigError, match=r"`dtype` is 'float64'"):
        RuntimeConfig(dtype="float64")  # type: ignore[arg-type]


def test_runtime_config_refuses_autocast_with_auto_and_names_no_torch_dtype() -> None:
    with pytest.raises(ConfigError, match=r"autocast.*auto"):
        RuntimeConfig(dtype="auto", autocast=True)
    with pytest.raises(ConfigError, match="resolved"):
        _ = RuntimeConfig(dtype="auto").torch_dtype


def _big_enough(monkeypatch: pytest.MonkeyPatch, support: rd.CpuBf16Support) -> None:
    """A tiny model counts as large and the CPU as `support`."""
    monkeypatch.setattr(rd, "AUTO_BF16_MIN_UNET_PARAMS", 0)
    monkeypatch.setattr(rd, "detect_cpu_bf16", lambda **_: support)


def test_bf16_path_is_close_to_float32_on_the_same_noise(monkeypatch: pytest.MonkeyPatch) -> None:
    _big_enough(monkeypatch, AMX)
    cond = random_conditions(2, 64, seed=3)
    sampling = SamplingConfig(num_inference_steps=4, scheduler="dpmpp-2m")
    ref = RelightPipeline(build_model(get_preset("tiny"), seed=1), RuntimeConfig(dtype="float32"))
    fast = RelightPipeline(build_model(get_preset("tiny"), seed=1), RuntimeConfig(dtype="auto"))
    assert fast.runtime.dtype == "bfloat16" and fast.dtype == torch.bfloat16
    assert fast.dtype_choice.reason == "auto: the CPU has AMX-BF16"
    # channels-last convolutions on the bf16 CPU path only; float32 keeps its layout (same pixels)
    assert fast.model.unet.conv_in.weight.is_contiguous(memory_format=torch.channels_last)
    assert not ref.model.unet.conv_in.weight.is_contiguous(memory_format=torch.channels_last)
    a = ref(cond, sampling, seeds=[0, 1]).images
    b = fast(cond, sampling, seeds=[0, 1]).images
    assert b.dtype == torch.float32 and torch.isfinite(b).all()
    psnr = 10 * torch.log10(1.0 / ((a - b) ** 2).mean())
    assert psnr > 30.0, float(psnr)
    assert not torch.equal(a, b)  # it really ran in bf16


def test_auto_on_a_cpu_without_bf16_is_float32_bit_for_bit(monkeypatch: pytest.MonkeyPatch) -> None:
    _big_enough(monkeypatch, AVX2)
    cond = random_conditions(1, 64, seed=4)
    sampling = SamplingConfig(num_inference_steps=2)
    auto = RelightPipeline(build_model(get_preset("tiny")), RuntimeConfig(dtype="auto"))
    ref = RelightPipeline(build_model(get_preset("tiny")), RuntimeConfig(dtype="float32"))
    assert auto.runtime.dtype == "float32" and "no native bf16" in auto.dtype_choice.reason
    assert torch.equal(
        auto(cond, sampling, seeds=[0]).images, ref(cond, sampling, seeds=[0]).images
    )


def test_dpm_solver_runs_is_the_old_spelling_and_takes_v_prediction() -> None:
    from gaffer_diffusion import SchedulerConfig

    pipe = RelightPipeline(build_model(get_preset("tiny"), seed=0))
    cond = random_conditions(1, 64, seed=0)
    out = {
        name: pipe(cond, SamplingConfig(num_inference_steps=3, scheduler=name), seeds=[0]).images
        for name in ("dpmpp-2m", "dpmsolver++", "unipc", "ddim")
    }
    assert torch.equal(out["dpmpp-2m"], out["dpmsolver++"])
    assert not torch.equal(out["dpmpp-2m"], out["ddim"])
    v = SchedulerConfig(prediction_type="v_prediction", timestep_spacing="trailing")
    for name in ("dpmpp-2m", "unipc"):
        s = make_scheduler(name, v)
        assert s.config.prediction_type == "v_prediction"
    cfg = dataclasses.replace(get_preset("tiny"), scheduler=v)
    vpipe = RelightPipeline(build_model(cfg, seed=0))
    sampled = vpipe(cond, SamplingConfig(num_inference_steps=3, scheduler="dpmpp-2m"), seeds=[0])
    assert torch.isfinite(sampled.images).all()
    # a prediction type the solvers do not convert (past SchedulerConfig's own check) is refused
    odd = SchedulerConfig()
    object.__setattr__(odd, "prediction_type", "flow_prediction")
    with pytest.raises(ConfigError, match=r"prediction type 'flow_prediction'.*--scheduler ddim"):
        make_scheduler("dpmpp-2m", odd)


def test_multistep_refusals() -> None:
    with pytest.raises(ConfigError, match=r"needs >= 2 steps.*--steps 20"):
        SamplingConfig(num_inference_steps=1, scheduler="dpmpp-2m")
    with pytest.raises(ConfigError, match=r"eta.*deterministic"):
        SamplingConfig(num_inference_steps=20, scheduler="unipc", eta=0.5)
    SamplingConfig(num_inference_steps=1, scheduler="ddim")  # DDIM at one step is fine


def _relight_args(*extra: str) -> list[str]:
    return ["relight", "x.png", "--envmap", "city", "--out", "o.png", *extra]


def test_cli_flags_defaults_and_bad_input(capsys: pytest.CaptureFixture[str]) -> None:
    args = _parser().parse_args(_relight_args())
    assert args.dtype == "auto" and args.scheduler == "ddim"  # DDIM stays the default
    assert _runtime(args).dtype == "auto"  # resolved by the pipeline, for the loaded model
    for flag, bad in (("--dtype", "float64"), ("--scheduler", "euler")):
        with pytest.raises(SystemExit) as exc:
            _parser().parse_args(_relight_args(flag, bad))
        assert exc.value.code == 2
        assert f"argument {flag}: invalid choice: '{bad}'" in capsys.readouterr().err
    with pytest.raises(ConfigError, match=r"--autocast.*--dtype auto.*--dtype float16"):
        _runtime(_parser().parse_args(_relight_args("--autocast")))
    ok = _parser().parse_args(_relight_args("--scheduler", "dpmpp-2m", "--dtype", "bfloat16"))
    assert ok.scheduler == "dpmpp-2m" and _runtime(ok).dtype == "bfloat16"


def test_one_photo_is_encoded_once_for_many_lightings(monkeypatch: pytest.MonkeyPatch) -> None:
    model = build_model(get_preset("tiny"), seed=2)
    cond = random_conditions(3, 64, seed=5)
    photo = cond.image[:1]
    many = RelightingConditions(image=photo.expand(3, -1, -1, -1), lighting=cond.lighting)
    calls: list[int] = []
    real = model.image_encoder.forward

    def counting(*args: object, **kwargs: object) -> object:
        calls.append(int(kwargs["pixel_values"].shape[0]))  # type: ignore[union-attr]
        return real(*args, **kwargs)

    monkeypatch.setattr(model.image_encoder, "forward", counting)
    for mode in ("mode", "sample"):
        calls.clear()
        gens = [torch.Generator().manual_seed(i) for i in range(3)]
        together = encode_conditions(
            model, many, latent_mode=mode, generator=gens if mode == "sample" else None
        )
        assert calls == [1]  # CLIP saw the photo once, not three times
        gens = [torch.Generator().manual_seed(i) for i in range(3)]
        alone = [
            encode_conditions(
                model,
                RelightingConditions(
                    image=photo,
                    lighting=LightingMaps(
                        ldr=cond.lighting.ldr[i : i + 1], hdr=cond.lighting.hdr[i : i + 1]
                    ),
                ),
                latent_mode=mode,
                generator=[gens[i]] if mode == "sample" else None,
            )
            for i in range(3)
        ]
        for field in ("image_latents", "hdr_latents", "ldr_latents", "clip_embeds"):
            torch.testing.assert_close(
                getattr(together, field), torch.cat([getattr(a, field) for a in alone])
            )
    # a batch of two photos, each under two lightings: each photo encoded once, alone, and every
    # item's latents are the ones it gets when encoded alone (batching does not change results)
    other = 1.0 - photo
    mixed = RelightingConditions(
        image=torch.cat([photo, other, photo, other]),
        lighting=LightingMaps(
            ldr=torch.cat([cond.lighting.ldr, cond.lighting.ldr[:1]]),
            hdr=torch.cat([cond.lighting.hdr, cond.lighting.hdr[:1]]),
        ),
    )
    calls.clear()
    both = encode_conditions(model, mixed)
    assert calls == [1, 1]
    for i in range(4):
        one = encode_conditions(
            model,
            RelightingConditions(
                image=mixed.image[i : i + 1],
                lighting=LightingMaps(
                    ldr=mixed.lighting.ldr[i : i + 1], hdr=mixed.lighting.hdr[i : i + 1]
                ),
            ),
            photo_cache=PhotoEncodingCache(),
        )
        for field in ("image_latents", "hdr_latents", "ldr_latents", "clip_embeds"):
            assert torch.equal(getattr(both, field)[i : i + 1], getattr(one, field)), (i, field)
    # the pipeline keeps it for the next batch (the turntable's next frames) of the same photo
    pipe = RelightPipeline(model)
    calls.clear()
    pipe.encode(many)
    pipe.encode(many)
    assert calls == [1] and pipe._photo_cache.hits == 1
    pipe.encode(RelightingConditions(image=1.0 - many.image, lighting=cond.lighting))
    assert calls == [1, 1] and pipe._photo_cache.misses == 2
