"""numba kernels of :mod:`solvers.emd.dwk`: the fused per-face pass of the batched ADMM.

Arrays are ``(2F, B)`` float32: rows ``2f, 2f + 1`` hold face ``f``'s field in its
tangent frame (scaled by ``sqrt(a_f)``), columns are targets.  Faces are split into
``chunks`` processed in parallel; per-target sums are accumulated per chunk in float64
and reduced afterwards (no races, deterministic for a fixed chunk count).
"""

from __future__ import annotations

import numba
import numpy as np

from solvers.jit import cached_njit


@cached_njit(parallel=True, fastmath=True)
def admm_pass(data, proj, dual, work, weights, inv_rho, alpha, chunks,
              out_obj):  # pragma: no cover - compiled
    """One ADMM z/u-update for every face and target, in place.

    ``px = data + proj`` is the flow of the current coefficients (objective
    ``Σ_f w_f |px_f|`` summed into ``out_obj``); with ``z_old = work + dual + data``,
    ``v = α px + (1 - α) z_old + dual``, ``z = shrink(v, w_f / ρ)``, ``dual = v - z``
    and ``work = z - dual - data`` (the right-hand side of the next coefficient update).
    """
    n_faces = weights.shape[0]
    n_b = data.shape[1]
    per = (n_faces + chunks - 1) // chunks
    partial = np.zeros((chunks, n_b), np.float64)
    beta = np.float32(1.0) - alpha
    for ch in numba.prange(chunks):
        lo = ch * per
        hi = min(n_faces, lo + per)
        acc = partial[ch]
        for f in range(lo, hi):
            r0 = 2 * f
            r1 = r0 + 1
            wf = weights[f]
            for b in range(n_b):
                d0 = data[r0, b]
                d1 = data[r1, b]
                p0 = d0 + proj[r0, b]
                p1 = d1 + proj[r1, b]
                acc[b] += wf * np.sqrt(p0 * p0 + p1 * p1)
                u0 = dual[r0, b]
                u1 = dual[r1, b]
                v0 = alpha * p0 + beta * (work[r0, b] + u0 + d0) + u0
                v1 = alpha * p1 + beta * (work[r1, b] + u1 + d1) + u1
                nv = np.sqrt(v0 * v0 + v1 * v1)
                t = wf * inv_rho[b]
                s = np.float32(0.0)
                if nv > t:
                    s = np.float32(1.0) - t / nv
                z0 = s * v0
                z1 = s * v1
                u0 = v0 - z0
                u1 = v1 - z1
                dual[r0, b] = u0
                dual[r1, b] = u1
                work[r0, b] = z0 - u0 - d0
                work[r1, b] = z1 - u1 - d1
    for ch in range(chunks):
        for b in range(n_b):
            out_obj[b] += partial[ch, b]


@cached_njit(parallel=True, fastmath=True)
def dual_bound(data, dual_perp, weights, chunks, out_dot, out_ratio):  # pragma: no cover
    """Per target ``Σ_f u'_f · data_f`` and ``max_f |u'_f| / w_f`` of the projected
    scaled dual ``u'`` (for the lower bound ``ρ dot / max(1, ρ ratio)``)."""
    n_faces = weights.shape[0]
    n_b = data.shape[1]
    per = (n_faces + chunks - 1) // chunks
    dots = np.zeros((chunks, n_b), np.float64)
    ratios = np.zeros((chunks, n_b), np.float64)
    for ch in numba.prange(chunks):
        lo = ch * per
        hi = min(n_faces, lo + per)
        dacc = dots[ch]
        racc = ratios[ch]
        for f in range(lo, hi):
            r0 = 2 * f
            r1 = r0 + 1
            inv_w = 1.0 / weights[f]
            for b in range(n_b):
                u0 = dual_perp[r0, b]
                u1 = dual_perp[r1, b]
                dacc[b] += u0 * data[r0, b] + u1 * data[r1, b]
                r = np.sqrt(u0 * u0 + u1 * u1) * inv_w
                if r > racc[b]:
                    racc[b] = r
    for ch in range(chunks):
        for b in range(n_b):
            out_dot[b] += dots[ch, b]
            if ratios[ch, b] > out_ratio[b]:
                out_ratio[b] = ratios[ch, b]


@cached_njit(parallel=True, fastmath=True)
def pair_l1(left, right, weights, rows, cols, tile, out):  # pragma: no cover - compiled
    """``out[p] = Σ_f w_f |left[rows[p], f] - right[cols[p], f]|`` (``d_W^0``).

    ``left (n, 2F)``, ``right (m, 2F)`` float32, one embedded field per row (face ``f`` at
    ``2f, 2f + 1``); pairs are split into blocks of 32 run in parallel, faces into tiles of
    ``tile`` so the fields of a block's pairs stay in cache; per pair the sum is float64
    over tiles in face order (deterministic whatever the thread count)."""
    n_faces = weights.shape[0]
    n_p = rows.shape[0]
    n_blocks = (n_p + 31) // 32
    for blk in numba.prange(n_blocks):
        lo = blk * 32
        hi = min(n_p, lo + 32)
        acc = np.zeros(hi - lo, np.float64)
        for f0 in range(0, n_faces, tile):
            f1 = min(n_faces, f0 + tile)
            for p in range(lo, hi):
                a = left[rows[p]]
                b = right[cols[p]]
                s = np.float32(0.0)
                for f in range(f0, f1):
                    d0 = a[2 * f] - b[2 * f]
                    d1 = a[2 * f + 1] - b[2 * f + 1]
                    s += weights[f] * np.sqrt(d0 * d0 + d1 * d1)
                acc[p - lo] += s
        for p in range(lo, hi):
            out[p] = acc[p - lo]
