"""``--device``: the one resolution of auto/cpu/cuda/cuda:N, the trainer's PPO update on that device (CPU results
bit for bit as before the option existed), checkpoints that load on any device, and the mixed precision of a GPU.

The CUDA tests run only where torch sees a GPU; this project's build machines have none, so they have not run yet.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import torch

from common.errors import OptionError
from common.policy import build_policy
from common.weights import (
    checkpoint_from_bytes,
    checkpoint_to_bytes,
    load_weights,
    state_dict_from_bytes,
    state_dict_to_bytes,
)
from racer.launcher import check_device_options
from trainer.device import check_device, resolve_device
from trainer.ppo import PPOBatch, minibatch_step, update
from trainer.precision import grad_scaler, precision_candidates
from trainer.process import make_optimizer

CUDA = torch.cuda.is_available()
needs_cuda = pytest.mark.skipif(not CUDA, reason="no CUDA device here (the CUDA path is unverified on this machine)")
SHAPE = (60, 80, 1)
"""A small camera frame: the shallow network's convolutions fit it and a CPU update takes a fraction of a second."""
DISCRETE = {"kind": "discrete", "n": 5}

RECORDED = {
    "policy_loss": -0.014472732320427895,
    "value_loss": 0.6274905751148859,
    "entropy": 1.6076402068138123,
    "approx_kl": 0.005996101846297582,
    "clip_fraction": 0.07291666666666667,
    "grad_norm": 3.8176511327425637,
    "explained_variance": 0.0034379959106445312,
    "epochs_run": 2.0,
    "epoch_kl": 0.007448310653368632,
}
"""``_update()``'s result from the trainer before ``--device`` existed (commit a2cac2c, an AMD EPYC): another CPU's
kernels may round differently in the last bits, hence the tolerance where it is compared."""


def _batch(n: int = 48) -> PPOBatch:
    g = torch.Generator().manual_seed(1)
    return PPOBatch(
        obs=torch.randint(0, 256, (n, *SHAPE), dtype=torch.uint8, generator=g),
        actions=torch.randint(0, 5, (n,), generator=g),
        old_logp=torch.full((n,), -1.6) + 0.1 * torch.randn(n, generator=g),
        advantages=torch.randn(n, generator=g),
        returns=torch.randn(n, generator=g) + 1.0,
        old_values=0.1 * torch.randn(n, generator=g),
    )


def _update(device: str | None, precision: str = "fp32") -> tuple[dict[str, float], torch.nn.Module, torch.optim.Adam]:
    """A fixed-seed PPO update (2 epochs of 3 minibatches): with ``device`` None as the trainer called ``update``
    before ``--device`` existed, else as ``Trainer`` does now (model and batch moved, precision and scaler for the
    device)."""
    torch.manual_seed(0)
    model = build_policy(SHAPE, DISCRETE)
    kwargs: dict = {}
    batch = _batch()
    if device is not None:
        on = resolve_device(device)
        (chosen,) = precision_candidates(precision, on)
        model.to(on).set_trunk_precision(chosen)
        batch, kwargs = batch.to(on), {"scaler": grad_scaler(chosen, on)}
    optimizer = make_optimizer(model, 3e-4, 0.0)
    result = update(
        model,
        optimizer,
        batch,
        epochs=2,
        minibatch_size=16,
        clip_eps=0.2,
        beta_entropy=0.01,
        value_coef=0.5,
        loss_type="huber",
        max_grad_norm=0.5,
        generator=torch.Generator().manual_seed(2),
        **kwargs,
    )
    return result, model, optimizer


# --- the option ------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["tpu", "cuda:x", "CUDA", "cuda:", "gpu", "", "cuda:-1", "cpu:0"])
def test_a_misspelt_device_is_an_option_error_naming_the_option_and_the_value(name):
    for check in (check_device, resolve_device):
        with pytest.raises(OptionError, match=rf"--device must be auto, cpu, cuda or cuda:N \(got '{name}'\)"):
            check(name)


def test_cpu_and_auto_resolve_here():
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto") == (torch.device("cuda", 0) if CUDA else torch.device("cpu"))


@pytest.mark.skipif(CUDA, reason="torch sees a CUDA device here")
@pytest.mark.parametrize("name", ["cuda", "cuda:0", "cuda:3"])
def test_cuda_without_cuda_is_an_option_error(name):
    with pytest.raises(OptionError, match=rf"--device {name}: torch .* has no CUDA device here"):
        resolve_device(name)


@needs_cuda
def test_a_gpu_index_beyond_the_gpus_is_an_option_error():
    count = torch.cuda.device_count()
    assert resolve_device(f"cuda:{count - 1}") == torch.device("cuda", count - 1)
    with pytest.raises(OptionError, match=rf"--device cuda:{count}: torch sees {count} CUDA device"):
        resolve_device(f"cuda:{count}")


def test_precisions_per_device():
    cpu = torch.device("cpu")
    with pytest.raises(OptionError, match="--precision 'fp16' is for CUDA devices"):
        precision_candidates("fp16", cpu)
    assert precision_candidates("bf16", cpu) == ("bf16",) and grad_scaler("bf16", cpu) is None
    with pytest.raises(OptionError, match="precision must be auto, fp32, bf16, fp16 .got 'half'"):
        precision_candidates("half", cpu)


def _racer(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "racer", *args]
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=120)


@pytest.mark.slow(reason="many cases, each a real env: over 6 s in all")
@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["train", "--device", "tpu"], "--device must be auto, cpu, cuda or cuda:N (got 'tpu')"),
        (["train", "--device", "cuda:x"], "(got 'cuda:x')"),
        (["trainer", "--redis", "redis://127.0.0.1:1/0", "--device", "tpu"], "(got 'tpu')"),
        (["evaluator", "--redis", "redis://127.0.0.1:1/0", "--run-id", "r", "--device", "tpu"], "(got 'tpu')"),
        (["eval", "--run-id", "never-ran", "--device", "tpu"], "(got 'tpu')"),
        *(
            []
            if CUDA
            else [
                (["train", "--device", "cuda"], "--device cuda: torch"),
                (["train", "--device", "cuda:3"], "--device cuda:3: torch"),
                (["train", "--precision", "fp16"], "--precision 'fp16' is for CUDA devices"),
                (["trainer", "--redis", "redis://127.0.0.1:1/0", "--device", "cuda"], "--device cuda: torch"),
            ]
        ),
    ],
    ids=lambda v: " ".join(v) if isinstance(v, list) else "",
)
def test_every_command_refuses_a_bad_device_in_one_line_before_writing_anything(tmp_path, args, expected):
    out = _racer(*args, "--store", str(tmp_path), cwd=tmp_path)
    assert out.returncode == 2, (out.stdout, out.stderr)
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and expected in lines[0], out.stderr
    assert list(tmp_path.iterdir()) == []


def test_racer_train_checks_the_default_device_without_loading_torch():
    code = (
        "import sys; from racer.launcher import check_device_options; "
        "[check_device_options(d, p) for d in ('auto', 'cpu') for p in ('auto', 'fp32')]; "
        "check_device_options('cpu', 'bf16'); print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "False"
    with pytest.raises(OptionError, match="got 'tpu'"):
        check_device_options("tpu", "auto")


# --- the same results on the CPU -------------------------------------------------------------------------------------


@pytest.mark.parametrize("device", ["cpu", "auto"] if not CUDA else ["cpu"])
def test_a_cpu_update_is_bit_for_bit_the_update_from_before_the_device_option(device):
    before, model_before, opt_before = _update(None)
    now, model_now, opt_now = _update(device)
    assert now == before
    for (name, a), b in zip(model_before.state_dict().items(), model_now.state_dict().values(), strict=True):
        assert torch.equal(a, b), name
    assert state_dict_to_bytes(opt_now.state_dict()) == state_dict_to_bytes(opt_before.state_dict())
    assert now == pytest.approx(RECORDED, rel=1e-4, abs=1e-6)  # and the figures recorded before the change


def test_cpu_checkpoint_bytes_are_torch_saves_own():
    import io

    _, model, optimizer = _update("cpu")
    for state in (model.state_dict(), optimizer.state_dict()):
        buf = io.BytesIO()
        torch.save(state, buf)
        assert state_dict_to_bytes(state) == buf.getvalue()


def test_a_cpu_batch_is_not_copied():
    batch = _batch()
    assert batch.to(torch.device("cpu")) is batch


def test_loss_scaling_steps_and_skips_a_step_whose_gradients_overflow():
    """The fp16 path of ``minibatch_step``, on the CPU (torch's CPU autocast and GradScaler do fp16 too; racer
    refuses ``--precision fp16`` on a CPU only because it is slow there): a sane scale steps, an absurd one makes
    the fp16 gradients overflow, and the scaler skips that step and halves its scale."""
    for init_scale, skipped in ((2.0**16, False), (2.0**100, True)):
        torch.manual_seed(0)
        model = build_policy(SHAPE, DISCRETE)
        model.set_trunk_precision("fp16")
        optimizer = make_optimizer(model, 3e-4, 0.0)
        before = [p.detach().clone() for p in model.parameters()]
        scaler = torch.amp.GradScaler("cpu", init_scale=init_scale)
        stats = minibatch_step(
            model,
            optimizer,
            _batch(16),
            clip_eps=0.2,
            beta_entropy=0.01,
            value_coef=0.5,
            loss_type="huber",
            max_grad_norm=0.5,
            scaler=scaler,
        )
        moved = any(not torch.equal(a, b) for a, b in zip(before, model.parameters(), strict=True))
        assert stats["amp_skipped"] == float(skipped) and moved is not skipped, stats
        assert (stats["grad_norm"] == 0.0) is skipped and (scaler.get_scale() < init_scale) is skipped
        assert all(p.dtype == torch.float32 for p in model.parameters())


# --- CUDA (not run on this project's machines: they have no GPU) ----------------------------------------------------


@needs_cuda
def test_an_fp32_update_on_cuda_matches_the_cpu_within_tolerance():
    cpu, cpu_model, _ = _update("cpu")
    gpu, gpu_model, gpu_opt = _update("cuda", "fp32")
    assert next(gpu_model.parameters()).device.type == "cuda"
    # Same shuffles (a CPU generator), so the same minibatches; cuDNN may use TF32 for the convolutions.
    for key in ("policy_loss", "value_loss", "entropy", "grad_norm"):
        assert gpu[key] == pytest.approx(cpu[key], rel=2e-2, abs=2e-3), key
    for (name, a), b in zip(cpu_model.state_dict().items(), gpu_model.state_dict().values(), strict=True):
        torch.testing.assert_close(b.cpu(), a, rtol=2e-2, atol=2e-3, msg=name)
    assert gpu_opt.defaults["fused"] is True


@needs_cuda
@pytest.mark.parametrize("precision", ["auto", "fp16"])
def test_autocast_on_cuda_keeps_the_weights_and_adams_state_fp32(precision):
    result, model, optimizer = _update("cuda", precision)
    chosen = precision_candidates(precision, resolve_device("cuda"))[0]
    assert model.trunk_dtype == {"bf16": torch.bfloat16, "fp16": torch.float16}[chosen]
    assert all(torch.isfinite(torch.tensor(v)) for v in result.values()), result
    assert all(p.dtype == torch.float32 and p.device.type == "cuda" for p in model.parameters())
    for state in optimizer.state.values():
        assert state["exp_avg"].dtype == state["exp_avg_sq"].dtype == torch.float32
    assert ("amp_skipped" in result) == (chosen == "fp16")
    with torch.no_grad():
        logits, value = model(_batch(4).obs.cuda())
    assert logits.dtype == value.dtype == torch.float32  # the heads read float32 features


@needs_cuda
def test_a_checkpoint_saved_on_cuda_loads_on_the_cpu():
    _, gpu_model, gpu_opt = _update("cuda", "fp32")
    model_sd, optim_sd = checkpoint_from_bytes(checkpoint_to_bytes(gpu_model.state_dict()))
    assert optim_sd is None and all(t.device.type == "cpu" for t in model_sd.values())
    cpu_model = build_policy(SHAPE, DISCRETE)
    load_weights(cpu_model, model_sd, "a CUDA checkpoint")
    for (name, a), b in zip(gpu_model.state_dict().items(), cpu_model.state_dict().values(), strict=True):
        assert torch.equal(a.cpu(), b), name
    cpu_opt = make_optimizer(cpu_model, 3e-4, 0.0)
    cpu_opt.load_state_dict(state_dict_from_bytes(state_dict_to_bytes(gpu_opt.state_dict())))
    assert all(s["exp_avg"].device.type == "cpu" for s in cpu_opt.state.values())


@needs_cuda
def test_the_evaluator_acts_on_cuda_with_a_checkpoint_saved_from_cuda(tmp_path):
    from common.defaults import DEFAULT_TRACK
    from common.policy import action_space_spec
    from model_store import LocalStore, RunStore
    from model_store.localize import localize_env
    from racer.runconfig import build_run
    from sim.env import RacerEnv
    from trainer.evaluator import EvalSettings, evaluate_checkpoint

    run, files = build_run("gpu", track=DEFAULT_TRACK)
    runs = RunStore(LocalStore(tmp_path / "store"))
    for name, data in files.items():
        runs.write_file("gpu", name, data)
    env_cfg = localize_env(run, runs, tmp_path)
    actions = RacerEnv(config=env_cfg).actions
    model = build_policy((120, 160, 1), action_space_spec(actions), run.policy).cuda()
    runs.save_checkpoint("gpu", 0, checkpoint_to_bytes(model.state_dict()), {"env_steps": 0})
    settings = EvalSettings(episodes=1, both_directions=False, action_noise=0.0)
    on_gpu = evaluate_checkpoint(runs, run, env_cfg, 0, settings, device=resolve_device("cuda"))
    on_cpu = evaluate_checkpoint(runs, run, env_cfg, 0, settings, device="cpu")
    assert on_gpu["episodes"] == on_cpu["episodes"] == 1 and 0 <= on_gpu["mean_progress"] <= 100
