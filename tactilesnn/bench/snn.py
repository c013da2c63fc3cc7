"""SNN simulation speed on CPU against snnTorch, Norse and SpikingJelly, with the matmul roofline.

Workload (issue: models): 96 inputs -> Linear -> 128 LIF -> Linear -> 10 LIF, T = 500, batch 64,
float32, Bernoulli(0.05) input spikes; forward only, and forward + backward + Adam step; 1 and 2
threads; medians. Peers are optional benchmark dependencies, skipped when not installed. Each
peer's forward output is checked against our plain reference loop where its neuron model matches
(subtract reset, same beta, threshold 1).
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import torch
from torch import nn

from ..core.device import resolve_device, synchronize
from ..models.functional import lif_scan
from ..models.snn import LIFLayer

T, B, N_IN, N_H, N_OUT = 500, 64, 96, 128, 10
CPU = torch.device("cpu")
BETA = 0.95


def _median_ms(fn: Callable[[], object], repeats: int, device: torch.device = CPU) -> float:
    fn()
    synchronize(device)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        synchronize(device)  # CUDA kernels run asynchronously: time their completion
        times.append(time.perf_counter() - t0)
    return 1000 * statistics.median(times)


class Ours(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        tau = -1.0 / torch.log(torch.tensor(BETA)).item()
        self.l1 = LIFLayer(N_IN, N_H, tau_mem_ms=tau, dt_ms=1.0)
        self.l2 = LIFLayer(N_H, N_OUT, tau_mem_ms=tau, dt_ms=1.0)

    def forward(self, x):
        return self.l2(self.l1(x)[0])[0]


def reference_forward(model: Ours, x: torch.Tensor) -> torch.Tensor:
    """Plain per-step loop with the same weights (no custom autograd, no hoisting)."""
    with torch.no_grad():
        h, _ = lif_scan(model.l1.fc(x), torch.zeros(B, N_H, device=x.device), BETA, 1.0, True)
        o, _ = lif_scan(model.l2.fc(h), torch.zeros(B, N_OUT, device=x.device), BETA, 1.0, True)
    return o


def _snntorch_peer() -> nn.Module:
    """snnTorch (Leaky, step loop)."""
    import snntorch as snn

    class SnnTorch(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.fc1, self.fc2 = nn.Linear(N_IN, N_H), nn.Linear(N_H, N_OUT)
            self.lif1 = snn.Leaky(beta=BETA, threshold=1.0, reset_mechanism="subtract")
            self.lif2 = snn.Leaky(beta=BETA, threshold=1.0, reset_mechanism="subtract")

        def forward(self, x):
            m1, m2 = self.lif1.init_leaky(), self.lif2.init_leaky()
            out = []
            for xt in x:
                s1, m1 = self.lif1(self.fc1(xt), m1)
                s2, m2 = self.lif2(self.fc2(s1), m2)
                out.append(s2)
            return torch.stack(out)

    return SnnTorch()


def _norse_peer() -> nn.Module:
    """Norse (LIF)."""
    import norse.torch as norse

    class Norse(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            p = norse.LIFParameters(v_th=torch.tensor(1.0))
            self.fc1, self.fc2 = nn.Linear(N_IN, N_H), nn.Linear(N_H, N_OUT)
            self.lif1, self.lif2 = norse.LIF(p), norse.LIF(p)

        def forward(self, x):
            h, _ = self.lif1(self.fc1(x))
            o, _ = self.lif2(self.fc2(h))
            return o

    return Norse()


def _spikingjelly_peer() -> nn.Module:
    """SpikingJelly (multi-step)."""
    from spikingjelly.activation_based import functional, layer, neuron

    class SJ(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.net = nn.Sequential(
                layer.Linear(N_IN, N_H, step_mode="m"),
                neuron.LIFNode(tau=1 / (1 - BETA), v_reset=None, step_mode="m", decay_input=False),
                layer.Linear(N_H, N_OUT, step_mode="m"),
                neuron.LIFNode(tau=1 / (1 - BETA), v_reset=None, step_mode="m", decay_input=False),
            )

        def forward(self, x):
            functional.reset_net(self.net)
            return self.net(x)

    return SJ()


def _peers(model: Ours) -> dict[str, nn.Module]:
    """The installed peers, each with our weights where its layout allows."""
    makers = (
        ("snntorch", "snnTorch (Leaky, step loop)", _snntorch_peer),
        ("norse", "Norse (LIF)", _norse_peer),
        ("spikingjelly", "SpikingJelly (multi-step)", _spikingjelly_peer),
    )
    peers = {label: make() for pkg, label, make in makers if importlib.util.find_spec(pkg)}
    for m in peers.values():  # same weights as ours where the layout allows
        lin = [mod for mod in m.modules() if isinstance(mod, nn.Linear)]
        with torch.no_grad():
            for dst, src in zip(lin, (model.l1.fc, model.l2.fc), strict=False):
                dst.weight.copy_(src.weight)
                dst.bias.copy_(src.bias)
    return peers


def matmul_gflops(threads: int, device: torch.device = CPU) -> float:
    torch.set_num_threads(threads)
    a, b = torch.randn(2048, 2048, device=device), torch.randn(2048, 2048, device=device)
    ms = _median_ms(lambda: a @ b, 5, device)
    return 2 * 2048**3 / (ms / 1000) / 1e9


def run(repeats: int = 7, device: str = "cpu") -> dict:
    """The rows on ``device`` (``cpu``: 1 and 2 threads; a CUDA device: one row per
    implementation, every model, input and optimizer on it)."""
    from ..core.perf import tune_allocator

    dev = resolve_device(device)
    results_alloc = tune_allocator()
    torch.manual_seed(0)
    x = (torch.rand(T, B, N_IN) < 0.05).float().to(dev)
    y = torch.randint(0, N_OUT, (B,)).to(dev)
    ours = Ours()
    models = {"tactilesnn (hoisted + reverse-scan backward)": ours, **_peers(ours)}
    for m in models.values():
        m.to(dev)
    with torch.no_grad():
        ref = reference_forward(ours, x)
        got = ours(x)
    results: dict = {
        "device": str(dev) if dev.type == "cpu" else f"{dev} ({torch.cuda.get_device_name(dev)})",
        "ours_equals_reference": bool(torch.equal(ref, got)),
        "allocator_tuned": results_alloc,
        "rows": [],
    }
    flops_fwd = 2 * T * B * (N_IN * N_H + N_H * N_OUT)
    for threads in (1, 2) if dev.type == "cpu" else (torch.get_num_threads(),):
        torch.set_num_threads(threads)
        gf = matmul_gflops(threads, dev)
        results[f"matmul_gflops_{threads}t"] = gf
        for name, m in models.items():
            opt = torch.optim.Adam(m.parameters(), lr=1e-3)

            def fwd(m=m):
                with torch.no_grad():
                    return m(x)

            def step(m=m, opt=opt):
                opt.zero_grad()
                out = m(x)
                loss = nn.functional.cross_entropy(out.sum(0), y)
                loss.backward()
                opt.step()

            row = {
                "impl": name,
                "threads": threads,
                "forward_ms": _median_ms(fwd, repeats, dev),
                "train_step_ms": _median_ms(step, max(3, repeats // 2), dev),
            }
            if name.startswith("snnTorch") or name.startswith("SpikingJelly"):
                with torch.no_grad():
                    row["max_abs_diff_vs_reference"] = float((m(x) - ref).abs().max())
            results["rows"].append(row)
        results[f"roofline_forward_ms_{threads}t"] = flops_fwd / (gf * 1e9) * 1000
    results["forward_matmul_mflop"] = flops_fwd / 1e6
    results["table"] = format_table(results)
    print(results["table"])
    return results


def format_table(res: dict) -> str:
    threads = sorted({r["threads"] for r in res["rows"]})
    lines = [
        f"device {res.get('device', 'cpu')}; forward matmul work "
        f"{res['forward_matmul_mflop']:.0f} MFLOP; measured GEMM "
        + ", ".join(f"{res[f'matmul_gflops_{t}t']:.0f} GFLOP/s ({t} thread(s))" for t in threads)
        + "; roofline "
        + " / ".join(f"{res[f'roofline_forward_ms_{t}t']:.3f}" for t in threads)
        + " ms",
        f"ours equals the plain reference loop: {res['ours_equals_reference']}",
        "| implementation | threads | forward ms | train step ms | ours faster (fwd / train) |",
        "|---|---|---|---|---|",
    ]
    ours = {r["threads"]: r for r in res["rows"] if r["impl"].startswith("tactilesnn")}
    for r in res["rows"]:
        o = ours[r["threads"]]
        lines.append(
            f"| {r['impl']} | {r['threads']} | {r['forward_ms']:.1f} | {r['train_step_ms']:.1f} | "
            f"{r['forward_ms'] / o['forward_ms']:.1f}x / {r['train_step_ms'] / o['train_step_ms']:.1f}x |"
        )
    return "\n".join(lines)


HELP = "SNN training step against snnTorch, Norse and SpikingJelly (same network)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--repeats", type=int, default=7, help="timed runs per case")
    p.add_argument("--device", default="cpu",
                   help="cpu (1 and 2 threads), cuda or cuda:N (every implementation on that GPU), "
                   "or auto (a CUDA GPU when torch sees one)")  # fmt: skip


def main(out: Path | None, options: argparse.Namespace) -> int:
    from . import write_result

    write_result(out, "snn.json", run(repeats=options.repeats, device=options.device))
    return 0
