"""Where tensors are computed: ``"auto"`` (CUDA when this torch build sees a GPU, else the CPU),
``"cpu"``, ``"cuda"`` or ``"cuda:N"``. One resolver, so every command refuses an unusable device
with the same clear message instead of failing deep inside torch."""

from __future__ import annotations

import torch

from .checks import check_device_name


def resolve_device(name: str = "auto") -> torch.device:
    """The ``torch.device`` for ``name`` (see the module docstring); a CUDA device this machine
    lacks is a ValueError that says so."""
    check_device_name(name)
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda"):
        if not torch.cuda.is_available():
            raise ValueError(f"device {name!r}: this torch build or machine has no CUDA GPU "
                             "(use --device cpu or auto)")  # fmt: skip
        dev = torch.device(name)
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ValueError(f"device {name!r}: only {torch.cuda.device_count()} CUDA device(s)")
        return dev
    return torch.device("cpu")


def synchronize(device: torch.device) -> None:
    """Wait for the device's queued work (timings of asynchronous CUDA kernels)."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def seeded_normal(rows: int, cols: int, generator: torch.Generator) -> torch.Tensor:
    """``[rows, cols]`` float32 standard normal draws from ``generator`` (CPU; scale them in
    place); under ``torch.device("meta")`` (a model built to count its parameters before any
    memory is allocated) the shape alone: a draw or out-of-place arithmetic on meta tensors runs
    torch's Python reference kernels, whose first use imports torch._dynamo (~2.5 s a process),
    where in-place arithmetic does not."""
    if torch.get_default_device().type == "meta":
        return torch.empty(rows, cols)
    return torch.randn(rows, cols, generator=generator)
