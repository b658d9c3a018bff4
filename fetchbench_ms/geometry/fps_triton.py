"""Farthest-point sampling as one Triton kernel: the CUDA path of ``pointops.farthest_point_sample``.

The torch loop takes ``n`` sequential steps of about seven small kernels each; on a GPU
that is bound by kernel launches (2,048 + 512 + 128 steps per prediction). Here one
program per cloud runs all ``n`` steps: each step scans the cloud in blocks, updates the
nearest-pick distances kept in a scratch row and finds the first point at the largest
one (the torch loop's ``argmax`` rule). Triton is the JIT compiler that CUDA builds of
torch ship with: no extension is built. Imported only on CUDA (``pointops`` checks the
kernel against the greedy rule once per device and falls back to the loop otherwise).
"""
from __future__ import annotations

import torch
import triton
import triton.language as tl


@triton.jit
def _fps_kernel(xyz, nearest, out, N: tl.constexpr, n: tl.constexpr, BLOCK: tl.constexpr):
    # xyz: [B, 3, N] (coordinates in rows: coalesced loads); nearest: [B, N] scratch
    b = tl.program_id(0)
    xs = xyz + b * 3 * N
    ys = xs + N
    zs = ys + N
    near = nearest + b * N
    dst = out + b * n
    lane = tl.arange(0, BLOCK)
    current = tl.zeros((), dtype=tl.int32)
    for i in range(0, n):
        tl.store(dst + i, current.to(tl.int64))
        cx = tl.load(xs + current)
        cy = tl.load(ys + current)
        cz = tl.load(zs + current)
        best_val = tl.full((BLOCK,), -1.0, tl.float32)
        best_idx = tl.zeros((BLOCK,), dtype=tl.int32)
        for s in range(0, N, BLOCK):
            offs = s + lane
            mask = offs < N
            dx = tl.load(xs + offs, mask=mask, other=0.0) - cx
            dy = tl.load(ys + offs, mask=mask, other=0.0) - cy
            dz = tl.load(zs + offs, mask=mask, other=0.0) - cz
            d = (dx * dx + dy * dy) + dz * dz
            m = tl.minimum(tl.load(near + offs, mask=mask, other=-1.0), d)
            tl.store(near + offs, m, mask=mask)
            m = tl.where(mask, m, -1.0)
            better = m > best_val  # strict: each lane keeps its first (lowest) index on ties
            best_idx = tl.where(better, offs, best_idx)
            best_val = tl.where(better, m, best_val)
        top = tl.max(best_val, axis=0)
        current = tl.min(tl.where(best_val == top, best_idx, N), axis=0)  # the first index at the maximum


def farthest_point_sample_triton(points: torch.Tensor, n: int) -> torch.Tensor:
    """Indices [B, n] of the farthest-point samples of ``points`` [B, N, 3] from index 0."""
    B, N, _ = points.shape
    xyz = points.detach().float().transpose(1, 2).contiguous()
    nearest = torch.full((B, N), float("inf"), device=points.device)
    out = torch.empty((B, n), dtype=torch.long, device=points.device)
    block = min(4096, triton.next_power_of_2(N))  # 4096: 5 blocks a step for 20k points, 8 values a thread
    _fps_kernel[(B,)](xyz, nearest, out, N, n, BLOCK=block, num_warps=max(1, min(16, block // 256)))
    return out
