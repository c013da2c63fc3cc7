"""The ``serve`` command's flags and action, importable without torch: ``tactilesnn serve`` and
``python -m tactilesnn.service`` (a deployment with numpy, onnxruntime, starlette and uvicorn
only) share them."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence


def _port(text: str) -> int:
    try:
        port = int(text)
    except ValueError:
        port = -1
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"port must be an integer in 1-65535, got {text!r}")
    return port


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("model", help="model.onnx written by train or export")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on")
    p.add_argument("--port", type=_port, default=8000, help="TCP port (1-65535)")
    p.add_argument("--threads", type=int, default=0, help="onnxruntime intra-op threads")
    p.add_argument("--stream-ttl-s", type=float, default=300.0,
                   help="drop a stream after this many seconds without a chunk")  # fmt: skip
    p.add_argument("--allowed-hosts", nargs="+", default=[], metavar="NAME",
                   help="extra host names browsers may use to reach the service (DNS-rebinding "
                        "guard; loopback names are always allowed; '*' turns the check off)")  # fmt: skip


def run(args: argparse.Namespace) -> int:
    from .app import serve

    if not (args.stream_ttl_s > 0 and math.isfinite(args.stream_ttl_s)):
        raise ValueError(f"--stream-ttl-s must be a positive number, got {args.stream_ttl_s}")
    serve(args.model, host=args.host, port=args.port, threads=args.threads,
          stream_ttl_s=args.stream_ttl_s, allowed_hosts=args.allowed_hosts)  # fmt: skip
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m tactilesnn.service MODEL [--port ...]``."""
    p = argparse.ArgumentParser(prog="python -m tactilesnn.service",
                                description="HTTP inference service (onnxruntime + numpy only)")  # fmt: skip
    add_arguments(p)
    args = p.parse_args(argv)
    try:
        return run(args)
    except (ValueError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
