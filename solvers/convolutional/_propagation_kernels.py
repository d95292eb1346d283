"""numba kernels of :mod:`solvers.convolutional.propagation` (one chunk of edge ends each).

A chunk is a few whole nodes of one color class and their edge ends (rows of the
log-scalings ``T``).  :func:`row_range` gives the shifts of the log-domain kernel
application (numpy's vectorized exp/log do the rest); :func:`update_nodes` is the Bregman
projection of every node of the chunk (barycenter or Sinkhorn update), its marginal gaps and
the over-relaxation, in one pass over the chunk's rows.  Both release the GIL, so chunks of
one color run in threads.

Compiled with ``cache=True`` (the first call in a fresh environment compiles for a few
seconds; later processes load the cache).
"""

from __future__ import annotations

import math

import numpy as np

from solvers.jit import cached_njit

# Marginal ratios above e^80 are clipped in the gap (it is then huge anyway).
_GAP_CLIP = 80.0
# Log-densities are clipped here before averaging: no -inf * 0 in the geometric mean.
_LOG_FLOOR = -1e300


@cached_njit(nogil=True)
def row_range(X):  # pragma: no cover - compiled
    """``(tops (k,), widest)``: every row's maximum (0 for an all ``-inf`` row) and the
    largest ``max - min`` of a row over its finite entries (the caller bands the rows when
    it exceeds one band)."""
    k, n = X.shape
    tops = np.empty(k)
    widest = 0.0
    for j in range(k):
        top = -np.inf
        low = np.inf
        for x in range(n):
            v = X[j, x]
            top = max(top, v)
            if v > -np.inf:
                low = min(low, v)
        if top == -np.inf:
            top = 0.0
        elif top - low > widest:
            widest = top - low
        tops[j] = top
    return tops, widest


@cached_njit(nogil=True)
def update_nodes(T, rows, starts, nodes, out, weights, fixed_slot, log_fixed, areas, omega,
                 log_bar, end_gap):  # pragma: no cover - compiled
    r"""Bregman projections of the chunk's nodes (thesis Alg. 4), in place.

    ``rows`` ``(k,)``: the chunk's rows of ``T``, node ``nodes[i]`` owning
    ``rows[starts[i]:starts[i+1]]``; ``out`` ``(k, n)``: :math:`\log H_t \exp(T_{opp})` per
    end, so an end's plan marginal at its node has the log-density ``T[row] + out``.

    * Fixed node (``fixed_slot[u] >= 0``): Sinkhorn update
      ``T[row] = log_fixed[slot] - out``; gap ``|| exp(T + out) - exp(log_fixed) ||_a``.
    * Free node: the weighted geometric mean (``weights`` per end, summing to 1 per node)
      of its ends' marginals, normalized to unit mass, becomes ``log_bar[u]`` and every end's
      target; gap ``<a exp(lbar), |expm1(old - new)|>``; the update of ``T`` is
      over-relaxed by ``omega`` (fixed nodes always take the plain update).

    ``end_gap[p]`` receives the gap of end ``rows[p]``; returns the largest.
    """
    n = T.shape[1]
    lbar = np.empty(n)
    bar_mass = np.empty(n)  # a exp(lbar): the barycenter's masses
    worst = 0.0
    for i in range(nodes.shape[0]):
        u = nodes[i]
        p0 = starts[i]
        p1 = starts[i + 1]
        slot = fixed_slot[u]
        if slot >= 0:
            for p in range(p0, p1):
                r = rows[p]
                gap = 0.0
                for x in range(n):
                    ld = T[r, x] + out[p, x]
                    target = log_fixed[slot, x]
                    gap += abs(math.exp(ld) - math.exp(target)) * areas[x]
                    T[r, x] = target - out[p, x]
                end_gap[p] = gap
                if gap > worst:
                    worst = gap
            continue
        for x in range(n):
            lbar[x] = 0.0
        for p in range(p0, p1):
            r = rows[p]
            w = weights[p]
            for x in range(n):
                ld = T[r, x] + out[p, x]
                if ld < _LOG_FLOOR:
                    ld = _LOG_FLOOR
                lbar[x] += w * ld
        top = -np.inf
        for x in range(n):
            if lbar[x] > top:
                top = lbar[x]
        mass = 0.0
        for x in range(n):
            mass += math.exp(lbar[x] - top) * areas[x]
        shift = top + math.log(mass)
        for x in range(n):
            lbar[x] -= shift
            log_bar[u, x] = lbar[x]
            bar_mass[x] = math.exp(lbar[x]) * areas[x]
        for p in range(p0, p1):
            r = rows[p]
            gap = 0.0
            for x in range(n):
                new = lbar[x] - out[p, x]
                old = T[r, x]
                delta = old - new
                if delta > _GAP_CLIP:
                    delta = _GAP_CLIP
                gap += bar_mass[x] * abs(math.expm1(delta))
                T[r, x] = old + omega * (new - old)
            end_gap[p] = gap
            if gap > worst:
                worst = gap
    return worst
