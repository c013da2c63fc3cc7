"""Fused LIF recurrence in C++ (float32, CPU), built once with the machine's compiler.

The pure-torch recurrence in :mod:`tactilesnn.models.snn` launches three kernels per time step;
for small layers the launches, not the flops, dominate. This extension runs the whole time loop in
one call, parallel over neurons. It is compiled on first use with ``torch.utils.cpp_extension``
(cached under ``~/.cache/torch_extensions``); if the build is impossible (no compiler, no ninja) or
``TACTILESNN_NO_EXT=1`` is set, :func:`kernel` returns None and the pure-torch path is used. Both
paths give identical spikes (tested).
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading

log = logging.getLogger("tactilesnn")

_SOURCE = r"""
#include <torch/extension.h>
#include <ATen/Parallel.h>

std::vector<torch::Tensor> lif_forward(torch::Tensor cur, torch::Tensor u0, double beta,
                                       double theta, bool subtract, bool save) {
  TORCH_CHECK(cur.scalar_type() == torch::kFloat32 && cur.is_contiguous(), "cur: contiguous f32");
  const int64_t T = cur.size(0);
  const int64_t N = T ? cur.numel() / T : 0;
  auto spikes = torch::empty_like(cur);
  auto u_all = save ? torch::empty_like(cur) : torch::empty({0}, cur.options());
  auto post = u0.contiguous().clone();
  const float* c = cur.data_ptr<float>();
  float* s = spikes.data_ptr<float>();
  float* p = post.data_ptr<float>();
  float* ua = save ? u_all.data_ptr<float>() : nullptr;
  const float b = (float)beta, th = (float)theta;
  at::parallel_for(0, N, 1024, [&](int64_t lo, int64_t hi) {
    for (int64_t t = 0; t < T; ++t) {
      const float* ct = c + t * N;
      float* st = s + t * N;
      for (int64_t i = lo; i < hi; ++i) {
        const float u = b * p[i] + ct[i];
        if (ua) ua[t * N + i] = u;
        const float sp = u >= th ? 1.f : 0.f;
        st[i] = sp;
        p[i] = subtract ? u - sp * th : (sp > 0.f ? 0.f : u);
      }
    }
  });
  return {spikes, post, u_all};
}

torch::Tensor lif_backward(torch::Tensor g_spikes, torch::Tensor u_all, torch::Tensor spikes,
                           torch::Tensor g_last, double beta, double theta, bool subtract,
                           int64_t kind, double alpha) {
  // a[t] = g_s[t] * surrogate'(u[t] - theta) (kind 0: fast sigmoid, 1: arctan);
  // g[t] = a[t] + carried; carried = g_last (t = T-1) or beta * g[t+1], gated by (1 - s[t])
  // for a reset to zero
  const int64_t T = g_spikes.size(0);
  const int64_t N = T ? g_spikes.numel() / T : 0;
  auto g = torch::empty_like(g_spikes);
  const float* pgs = g_spikes.data_ptr<float>();
  const float* pu = u_all.data_ptr<float>();
  const float* ps = spikes.data_ptr<float>();
  const float* gl = g_last.data_ptr<float>();
  float* pg = g.data_ptr<float>();
  const float b = (float)beta, th = (float)theta, al = (float)alpha;
  const float half_pi_al = 1.5707963267948966f * al;
  at::parallel_for(0, N, 1024, [&](int64_t lo, int64_t hi) {
    std::vector<float> carry(gl + lo, gl + hi);  // time outer, neurons inner: contiguous rows
    for (int64_t t = T - 1; t >= 0; --t) {
      const float* gst = pgs + t * N;
      const float* ut = pu + t * N;
      const float* st = ps + t * N;
      float* gt = pg + t * N;
      for (int64_t i = lo; i < hi; ++i) {
        const float x = ut[i] - th;
        float sg;
        if (kind == 0) {
          const float d = al * (x < 0.f ? -x : x) + 1.f;
          sg = 1.f / (d * d);
        } else {
          const float z = half_pi_al * x;
          sg = 0.5f * al / (1.f + z * z);
        }
        const float keep = subtract ? 1.f : 1.f - st[i];
        const float v = gst[i] * sg + carry[i - lo] * keep;
        gt[i] = v;
        carry[i - lo] = b * v;
      }
    }
  });
  return g;
}
"""

_kernel = None
_tried = False


def kernel():
    """The compiled module, or None when unavailable (the caller falls back to pure torch)."""
    global _kernel, _tried
    if _tried:
        return _kernel
    _tried = True
    if os.environ.get("TACTILESNN_NO_EXT"):
        return None
    try:
        from torch.utils.cpp_extension import load_inline

        name = build_name()
        cached = _is_built(name)
        with _elapsed_bar("fused LIF kernel (compiled once, then cached)", quiet=cached):
            _kernel = load_inline(
                name=name,
                cpp_sources=_SOURCE,
                functions=["lif_forward", "lif_backward"],
                extra_cflags=list(CFLAGS),
                extra_ldflags=list(LDFLAGS),
                verbose=False,
            )
    except Exception as e:  # no compiler / ninja / headers: pure torch still works
        log.warning("fused LIF kernel unavailable (%s); using the pure-torch recurrence", e)
        _kernel = None
    return _kernel


CFLAGS = ("-O3", "-fopenmp")
LDFLAGS = ("-fopenmp",)


def build_name() -> str:
    """The extension's name, from what its build depends on: the kernel source, torch's version
    and install location, the compiler, the flags and Python's ABI. Environments that differ in
    any of these build side by side under their own names (and never rebuild each other's);
    environments that agree share one build."""
    import hashlib
    import platform
    import shutil

    import torch

    cxx = os.environ.get("CXX", "c++")
    key = "\n".join([_SOURCE, torch.__version__, os.path.dirname(torch.__file__),
                      shutil.which(cxx) or cxx, " ".join(CFLAGS + LDFLAGS),
                      sys.implementation.cache_tag or "", platform.machine()])  # fmt: skip
    return "tactilesnn_lif_" + hashlib.sha256(key.encode()).hexdigest()[:16]


def _is_built(name: str) -> bool:
    """True when a build of ``name`` is in torch's extensions cache (loading it is quick)."""
    try:
        from torch.utils.cpp_extension import _get_build_directory

        folder = _get_build_directory(name, verbose=False)
    except Exception:  # a private helper: if it moves, assume a build
        return False
    return any(f.endswith(".so") for f in os.listdir(folder)) if os.path.isdir(folder) else False


@contextlib.contextmanager
def _elapsed_bar(desc: str, quiet: bool = False):
    """A ticking ``desc: elapsed`` line on stderr while a step of unknown length runs (the
    compile takes about a minute the first time); without a terminal (pipes, nohup, notebooks)
    one log line before and one with the time after. ``quiet``: nothing (a cached build)."""
    import time

    from tqdm.auto import tqdm

    if not sys.stderr.isatty():
        if quiet:
            yield
            return
        t0 = time.monotonic()
        print(f"{desc}: compiling (about a minute, once per environment)...", file=sys.stderr,
              flush=True)  # fmt: skip
        try:
            yield
        finally:
            print(f"{desc}: done in {time.monotonic() - t0:.0f} s", file=sys.stderr, flush=True)
        return
    bar = tqdm(desc=desc, bar_format="{desc}: {elapsed}", disable=quiet)
    stop = threading.Event()

    def tick() -> None:
        while not stop.wait(1.0):
            bar.refresh()

    t = threading.Thread(target=tick, daemon=True)
    t.start()
    try:
        yield
    finally:
        stop.set()
        t.join()
        bar.close()
