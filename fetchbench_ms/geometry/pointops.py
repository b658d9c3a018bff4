"""PointNet++'s point operations in plain torch (no compiled extension), batched, CPU or CUDA.

Every function takes batched tensors (``[B, N, 3]`` points) and returns indices or
features per batch element; all elements of a batch have the same number of points.
"""
from __future__ import annotations

import os
import warnings

import numpy as np
import torch

# Rows of centres handled at once in ``ball_query`` / ``knn``: bounds the [B, rows, N]
# distance block (2048 rows x 20k points x 4 B = 160 MB at the first level otherwise).
CHUNK = 512
COLUMN_BLOCK = 2048  # points of the cloud read at a time by the CPU's ball query


def farthest_point_sample(points: torch.Tensor, n: int, start: int = 0) -> torch.Tensor:
    """Indices [B, n] of ``n`` farthest points of ``points`` [B, N, 3], greedily, from index ``start``.

    ``n`` may exceed N only by repetition (then the last picks repeat points already taken).
    On CUDA the Triton kernel of ``fps_triton`` does it in one launch when it passed its
    check on this device (``fps_backend``), otherwise the torch loop; on the CPU a NumPy loop.
    """
    if start == 0 and n <= points.shape[1] and fps_backend(points.device) == "triton":
        from .fps_triton import farthest_point_sample_triton

        try:
            return farthest_point_sample_triton(points, n)
        except Exception as error:  # e.g. a size it cannot compile for: the loop from now on
            _FPS_BACKENDS[_device_key(points.device)] = "torch"
            warnings.warn(f"Triton farthest-point sampling failed ({type(error).__name__}: {error}); using the torch loop")
    if points.device.type == "cpu":
        return farthest_point_sample_numpy(points, n, start)
    return farthest_point_sample_loop(points, n, start)


def farthest_point_sample_loop(points: torch.Tensor, n: int, start: int = 0) -> torch.Tensor:
    """``farthest_point_sample`` as ``n`` steps of torch operations (any device)."""
    B, N, _ = points.shape
    out = torch.empty((B, n), dtype=torch.long, device=points.device)
    nearest = torch.full((B, N), float("inf"), device=points.device, dtype=points.dtype)
    rows = torch.arange(B, device=points.device)
    current = torch.full((B,), start, dtype=torch.long, device=points.device)
    for i in range(n):
        out[:, i] = current
        d = ((points - points[rows, current][:, None, :]) ** 2).sum(-1)
        nearest = torch.minimum(nearest, d)
        current = nearest.argmax(-1)
    return out


def farthest_point_sample_numpy(points: torch.Tensor, n: int, start: int = 0) -> torch.Tensor:
    """``farthest_point_sample`` on the CPU as a NumPy loop over coordinate rows.

    Hand-written because no installed library has it, and because the torch loop is slow on
    a CPU: its 2,048 steps a level are ~10 small ops each, and torch's per-op overhead and
    OpenMP hand-offs dominate (0.5 s on one thread for 20k points, 20 s with two threads on a
    busy machine); NumPy's in-place ops on contiguous x, y, z rows take 0.06 s, single-threaded.
    The distances are summed in the torch loop's order (x, y, z), so the picks are the same.
    """
    P = points.detach().numpy()
    B, N, _ = P.shape
    out = np.empty((B, n), np.int64)
    for b in range(B):
        x, y, z = (np.ascontiguousarray(P[b, :, k]) for k in range(3))
        nearest = np.full(N, np.inf, dtype=P.dtype)
        d, t = np.empty(N, P.dtype), np.empty(N, P.dtype)
        current = start
        for i in range(n):
            out[b, i] = current
            np.subtract(x, x[current], out=d)
            np.multiply(d, d, out=d)
            np.subtract(y, y[current], out=t)
            np.multiply(t, t, out=t)
            d += t
            np.subtract(z, z[current], out=t)
            np.multiply(t, t, out=t)
            d += t
            np.minimum(nearest, d, out=nearest)
            current = int(nearest.argmax())
    return torch.from_numpy(out)


def is_farthest_point_sequence(points: torch.Tensor, index: torch.Tensor, rtol: float = 1e-5) -> bool:
    """Whether ``index`` [B, n] is a greedy farthest-point order of ``points`` [B, N, 3] (each
    pick at the largest distance to the picks before it, up to ``rtol``) starting at 0."""
    B, N, _ = points.shape
    if index.shape[0] != B or bool((index < 0).any() or (index >= N).any()) or bool((index[:, 0] != 0).any()):
        return False
    rows = torch.arange(B, device=points.device)
    nearest = torch.full((B, N), float("inf"), device=points.device, dtype=points.dtype)
    for i in range(index.shape[1]):
        if i > 0 and bool((nearest[rows, index[:, i]] < nearest.max(-1).values * (1 - rtol)).any()):
            return False
        nearest = torch.minimum(nearest, ((points - points[rows, index[:, i]][:, None, :]) ** 2).sum(-1))
    return True


_FPS_BACKENDS: dict[str, str] = {}


def _device_key(device: torch.device) -> str:
    """"cuda:0" for "cuda" too, so that a device is checked once."""
    if device.type == "cuda" and device.index is None:
        device = torch.device("cuda", torch.cuda.current_device())
    return str(device)


def fps_backend(device: torch.device) -> str:
    """"triton" or "torch": the Triton kernel on CUDA devices where it imports, compiles and
    picks a greedy farthest-point order of a random test cloud (checked once per device;
    ``FETCHBENCH_FPS=torch`` forces the loop), else the torch loop."""
    device = torch.device(device)
    if device.type != "cuda" or os.environ.get("FETCHBENCH_FPS", "auto") == "torch":
        return "torch"
    key = _device_key(device)
    if key not in _FPS_BACKENDS:
        _FPS_BACKENDS[key] = "torch"
        try:
            from .fps_triton import farthest_point_sample_triton

            generator = torch.Generator(device="cpu").manual_seed(0)
            cloud = (torch.randn(2, 5000, 3, generator=generator) * 0.1).to(device)
            if is_farthest_point_sequence(cloud, farthest_point_sample_triton(cloud, 256)):
                _FPS_BACKENDS[key] = "triton"
            else:
                warnings.warn("the Triton farthest-point kernel failed its check on this device; using the torch loop")
        except Exception as error:  # no Triton, or it cannot compile here: the loop is always right
            warnings.warn(f"Triton farthest-point sampling unavailable ({type(error).__name__}: {error}); "
                          "using the torch loop")
    return _FPS_BACKENDS[key]


def gather(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """``values`` [B, N, C] at ``index`` [B, ...] -> [B, ..., C]."""
    B = values.shape[0]
    flat = index.reshape(B, -1)
    picked = torch.gather(values, 1, flat[..., None].expand(-1, -1, values.shape[-1]))
    return picked.reshape(*index.shape, values.shape[-1])


def _squared_distances(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """[B, M, N] squared distances between a [B, M, 3] and b [B, N, 3]: from differences,
    not the |a|^2 + |b|^2 - 2ab expansion (its cancellation moves points across a 2 cm
    radius), and without a [B, M, N, 3] temporary (3.5x faster than broadcasting).

    On a GPU the sum of the three coordinates' squared differences, one [B, M, N] term at a
    time: torch's CUDA ``cdist`` without the matrix product is a general-p kernel that took
    77-90 % of the network's GPU time (H100 profile, 2026-11-23); on the CPU ``cdist`` is the
    faster of the two."""
    if a.device.type == "cpu":
        return torch.cdist(a, b, compute_mode="donot_use_mm_for_euclid_dist").square_()
    return _squared_distances_by_coordinate(a, b)


def _squared_distances_by_coordinate(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    d2 = (a[..., 0, None] - b[..., None, :, 0]).square_()
    d2 += (a[..., 1, None] - b[..., None, :, 1]).square_()
    d2 += (a[..., 2, None] - b[..., None, :, 2]).square_()
    return d2


def ball_query(points: torch.Tensor, centers: torch.Tensor, radius, k: int):
    """Indices [B, M, k] of up to ``k`` points within ``radius`` of each centre, the first ones
    in index order (PointNet++'s and torch_cluster's ``radius`` rule; a shuffled cloud makes
    them a random subset). Centres with fewer neighbours repeat their first one; a centre
    with none (not itself a point of the cloud) gets its nearest point.

    ``radius`` may be a sequence of radii: then a list of index tensors, one per radius,
    sharing one distance computation (multi-scale grouping). On the CPU the cloud is read in
    blocks of columns until every centre has its ``k`` (``_ball_query_blocks``, the same
    answer); on other devices the whole distance matrix at once (``_ball_query_full``).
    """
    radii = [radius] if isinstance(radius, (int, float)) else list(radius)
    query = _ball_query_blocks if points.device.type == "cpu" else _ball_query_full
    result = query(points, centers, radii, k)
    return result[0] if isinstance(radius, (int, float)) else result


def _pad_neighbours(first: torch.Tensor, nearest: torch.Tensor, N: int, k: int) -> torch.Tensor:
    """[..., kk] first indices (N where missing) -> [..., k]: gaps take the first one, or the
    nearest point (``nearest`` [..., 1]) when there is none."""
    fallback = torch.where(first[..., :1] < N, first[..., :1], nearest)
    first = torch.where(first < N, first, fallback)
    if first.shape[-1] < k:
        first = torch.cat([first, fallback.expand(*first.shape[:-1], k - first.shape[-1])], -1)
    return first


def _ball_query_full(points, centers, radii, k):
    B, N, _ = points.shape
    arange = torch.arange(N, device=points.device)
    kk = min(k, N)
    out = [[] for _ in radii]
    for s in range(0, centers.shape[1], CHUNK):
        d2 = _squared_distances(centers[:, s:s + CHUNK], points)
        nearest = d2.argmin(-1, keepdim=True)
        for r, parts in zip(radii, out):
            order = torch.where(d2 <= r * r, arange, N)
            first = torch.topk(order, kk, dim=-1, largest=False, sorted=True).values
            parts.append(_pad_neighbours(first, nearest, N, k))
    return [torch.cat(parts, 1) for parts in out]


def _ball_query_blocks(points, centers, radii, k):
    """``ball_query`` reading the cloud ``COLUMN_BLOCK`` points at a time, each radius only
    for the centres still short of ``k``. Hand-written for the CPU, where the whole
    [M, N] matrix, keyed and top-k'd once per radius, is most of the network's time: in a
    shuffled cloud most centres have their ``k`` within the first few thousand points
    (4x faster on the first level's 2,048 centres x 20k points)."""
    B, N, _ = points.shape
    M = centers.shape[1]
    kk = min(k, N)
    flat_centers = centers.reshape(B * M, 1, 3)
    batch_of_row = torch.arange(B).repeat_interleave(M)
    nearest_d2 = torch.full((B * M,), float("inf"), dtype=points.dtype)
    nearest = torch.zeros((B * M,), dtype=torch.long)
    first = [torch.full((B * M, kk), N, dtype=torch.long) for _ in radii]  # N: not found yet
    found = [torch.zeros(B * M, dtype=torch.long) for _ in radii]
    for c0 in range(0, N, COLUMN_BLOCK):
        short = [f < kk for f in found]
        rows_left = torch.nonzero(torch.stack(short).any(0))[:, 0]
        if len(rows_left) == 0:
            break
        cols = torch.arange(c0, min(N, c0 + COLUMN_BLOCK))
        for s in range(0, len(rows_left), CHUNK):
            rows = rows_left[s:s + CHUNK]
            if B == 1:
                block = points[:, c0:c0 + COLUMN_BLOCK].expand(len(rows), -1, -1)
            else:
                block = points[batch_of_row[rows], c0:c0 + COLUMN_BLOCK]
            d2 = _squared_distances(flat_centers[rows], block)[:, 0]  # [R, C]
            # The nearest point so far: the fallback of a centre with no point in a radius,
            # which stays short and so sees every block.
            value, at = d2.min(-1)
            closer = value < nearest_d2[rows]
            nearest_d2[rows] = torch.where(closer, value, nearest_d2[rows])
            nearest[rows] = torch.where(closer, cols[at], nearest[rows])
            for j, r in enumerate(radii):
                want = short[j][rows]
                if not bool(want.any()):
                    continue
                rj, inside = rows[want], d2[want] <= r * r
                taken = torch.topk(torch.where(inside, cols, N), min(kk, len(cols)), dim=-1, largest=False,
                                   sorted=True).values
                # This block's indices all follow the earlier blocks': sorting keeps the first kk.
                first[j][rj] = torch.sort(torch.cat([first[j][rj], taken], -1), -1).values[:, :kk]
                found[j][rj] += inside.sum(-1)
    return [_pad_neighbours(f, nearest[:, None], N, k).reshape(B, M, k) for f in first]


def knn(points: torch.Tensor, queries: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``k`` nearest ``points`` [B, N, 3] of each query [B, M, 3]: (indices [B, M, k],
    squared distances [B, M, k]), nearest first."""
    idx, dist = [], []
    for s in range(0, queries.shape[1], CHUNK):
        d2 = _squared_distances(queries[:, s:s + CHUNK], points)
        values, index = torch.topk(d2, min(k, points.shape[1]), dim=-1, largest=False, sorted=True)
        idx.append(index)
        dist.append(values)
    return torch.cat(idx, 1), torch.cat(dist, 1)


def knn_interpolate(features: torch.Tensor, points: torch.Tensor, queries: torch.Tensor, k: int = 3) -> torch.Tensor:
    """Features [B, N, C] known at ``points`` [B, N, 3], interpolated at ``queries`` [B, M, 3]
    by inverse squared distance over the ``k`` nearest points -> [B, M, C]. A query on a
    point takes that point's features."""
    index, d2 = knn(points, queries, k)
    weights = 1.0 / d2.clamp(min=1e-16)
    weights = weights / weights.sum(-1, keepdim=True)
    return (gather(features, index) * weights[..., None]).sum(-2)
