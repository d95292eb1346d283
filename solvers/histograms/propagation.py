r"""Propagation of histograms from labeled nodes to the rest of a graph (thesis §5.3, §5.5).

Semi-supervised learning of distributions: minimize the Dirichlet energy in :math:`W_2`,

.. math::  \min_{\{\mu_v\}_{v \notin V_0}} \sum_{(u, v) \in E} w_{uv}\, W_2^2(\mu_u, \mu_v),
           \qquad \mu_v \text{ given on } V_0 .

On Prob(ℝ) (Prop. 13) :math:`W_2^2(\mu, \nu) = \|F_\mu^{-1} - F_\nu^{-1}\|_{L^2}^2`, so the
optimum is the harmonic extension of the inverse CDFs, level by level: the Dirichlet
problem :math:`\Delta g(\cdot, s) = 0` on the unlabeled nodes, solved for all ``m``
levels at once (one factorization, one block solve; :mod:`solvers.histograms.dirichlet`)
and turned back into histograms on the input bins.  Prop. 14: means are harmonic and
standard deviations are at most the largest labeled one; Prop. 15: Dirac labels give the
classical harmonic interpolation of their positions.

Baselines (§5.2.2): ``method="pdf"`` extends the histograms bin by bin (the same Dirichlet
problem on densities; mixtures, hence multimodal); :func:`harmonic_means` is the
classical harmonic interpolation of the labeled means [ZGL03].
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from solvers.errors import InputError
from solvers.histograms.bins import Bins, check_histograms, histogram_of_samples, make_bins
from solvers.histograms.dirichlet import dirichlet_system, harmonic_extension
from solvers.histograms.quantiles import (
    histograms_from_inverse_cdf,
    inverse_cdf_from_density,
    inverse_cdf_from_histograms,
    inverse_cdf_from_samples,
    quantile_levels,
    sort_rows,
)
from solvers.monitor import SolverResult
from solvers.validation import check_choice

Method = Literal["wasserstein", "pdf"]


@dataclass(kw_only=True)
class HistogramPropagationResult(SolverResult):
    """Per-node distributions after :func:`propagate_histograms`.

    Attributes
    ----------
    iterations, residual, converged : int, float, bool
        Convergence data (:class:`~solvers.monitor.SolverResult`).
        ``residual`` is the measured relative residual of the linear solve; ``iterations``
        1 for a direct solve, CG iterations otherwise.
    method : {"wasserstein", "pdf"}
        The method used.
    histograms : (n, B) array or None
        Per-node histograms on ``bins`` (rows sum to 1; ``None`` without bins).
    quantiles : (n, m) array or None
        Inverse CDFs at ``levels`` (Wasserstein method).
    levels : (m,) array or None
        Quantile levels.
    bins : Bins or None
        The bins.
    labeled : (k,) int array
        The labeled nodes.
    rank : int
        Columns actually solved after compression.
    compression_error : float
        Largest truncation error on the labels.
    linear_method : str
        ``"direct"`` or ``"amg"``.
    """

    method: str
    histograms: np.ndarray | None
    quantiles: np.ndarray | None
    levels: np.ndarray | None
    bins: Bins | None
    labeled: np.ndarray
    rank: int = 0
    compression_error: float = 0.0
    linear_method: str = "direct"


def label_quantiles(levels: np.ndarray, *, bins: Bins | None = None, histograms=None,
                    samples=None, densities=None, field: str = "labels") -> np.ndarray:
    """Inverse CDFs of the labels, from exactly one of the three input forms.

    Parameters
    ----------
    levels : (m,) array
        Quantile levels in (0, 1).
    bins : Bins, optional
        Needed for ``histograms``; periodic bins wrap ``samples``.
    histograms : (k, B) array, optional
        Label histograms over ``bins``.
    samples : list of k arrays, optional
        Raw values of each label.
    densities : tuple, optional
        ``(knots (P,), values (k, P))``: piecewise-linear densities.
    field : str
        Input name given to the :class:`~solvers.errors.InputError` raised.

    Returns
    -------
    (k, m) array
    """
    given = [name for name, v in (("histograms", histograms), ("samples", samples),
                                  ("densities", densities)) if v is not None]
    if len(given) != 1:
        raise InputError("give exactly one of histograms, samples or densities for the "
                         f"labels (got {given or 'none'})", field="histograms")
    if histograms is not None:
        if bins is None:
            raise InputError("histograms need bins", field="bins")
        return inverse_cdf_from_histograms(histograms, bins, levels, "histograms")
    if samples is not None:
        return np.stack([inverse_cdf_from_samples(s, levels, bins, f"samples[{i}]")
                         for i, s in enumerate(samples)])
    try:
        knots, values = densities
    except (TypeError, ValueError) as exc:
        raise InputError("densities must be a pair (knots, values)", field="densities") from exc
    values = np.atleast_2d(np.asarray(values, dtype=np.float64))
    return np.stack([inverse_cdf_from_density(knots, v, levels, f"densities[{i}]")
                     for i, v in enumerate(values)])


def label_histograms(bins: Bins, *, histograms=None, samples=None, densities=None
                     ) -> np.ndarray:
    """Normalized histograms of the labels on ``bins`` (the PDF method's input).

    Parameters
    ----------
    bins : Bins
        The bins.
    histograms, samples, densities
        The labels, as in :func:`label_quantiles`.

    Returns
    -------
    (k, B) array
    """
    if histograms is not None:
        return check_histograms(histograms, bins.count, "histograms")
    if samples is not None:
        from solvers.histograms.bins import check_samples

        return np.stack([histogram_of_samples(check_samples(s, bins, f"samples[{i}]"), bins)
                         for i, s in enumerate(samples)])
    if densities is not None:
        fine = quantile_levels(4096)
        q = label_quantiles(fine, densities=densities)
        return histograms_from_inverse_cdf(q, fine, bins)
    raise InputError("give histograms, samples or densities for the labels",
                     field="histograms")


def _count_labels(histograms, samples, densities) -> int:
    if histograms is not None:
        return len(np.atleast_2d(np.asarray(histograms, dtype=object)))
    if samples is not None:
        return len(samples)
    if densities is not None:
        return len(np.atleast_2d(np.asarray(densities[1], dtype=object)))
    return 0


def check_label_count(labeled, histograms=None, samples=None, densities=None) -> None:
    k = _count_labels(histograms, samples, densities)
    if k != len(labeled):
        name = "histograms" if histograms is not None else (
            "samples" if samples is not None else "densities")
        raise InputError(f"{name} has {k} labels for {len(labeled)} labeled nodes",
                         field=name)


def propagate_histograms(graph, labeled, histograms=None, *, bins=None, samples=None,
                         densities=None, method: Method = "wasserstein", levels: int = 100,
                         laplacian: str = "auto", linear_method: str = "auto",
                         rank_tol: float = 1e-9, tol: float = 1e-10, max_iter: int = 500,
                         progress=None, should_cancel=None) -> HistogramPropagationResult:
    r"""Propagate labeled distributions to every node (Prop. 13; PDF baseline, §5.2.2).

    The Wasserstein method minimizes the Dirichlet energy in :math:`W_2`,

    .. math:: \min_{\mu_v,\, v \notin L} \sum_{(u, v)} w_{uv} W_2^2(\mu_u, \mu_v),

    which on the line is the harmonic extension of the inverse CDFs, one solve for all
    levels (Prop. 13).

    Parameters
    ----------
    graph : Graph, TriangleMesh, PointCloud, Grid or (n, n) sparse matrix
        The domain, or a symmetric non-negative weight matrix (see :mod:`.graphs`).
    labeled : (k,) int array
        Distinct node indices, at least one per connected component.
    histograms, samples, densities : optional
        The labels in one of three forms, as in :func:`label_quantiles`.
    bins : Bins or (B + 1,) array, optional
        Bins or their edges; needed for histogram inputs and outputs.
    method : {"wasserstein", "pdf"}
        Inverse CDFs (Prop. 13), or bin by bin (§5.2.2).
    levels : int
        Number ``m`` of quantile levels ``(k + 1/2)/m``.
    laplacian : {"auto", "robust", "cotan"}
        The Laplacian of a mesh (cotangent or robust); other domains have one.
    linear_method : {"auto", "direct", "amg"}
        Sparse Cholesky, or AMG-preconditioned CG.
    rank_tol : float
        Relative singular-value cut of the column compression.
    tol, max_iter : float, int
        Relative residual tolerance and iteration budget of CG (``linear_method="amg"``).
    progress, should_cancel : callable, optional
        ``progress(iteration, residual)`` as the solver advances; ``should_cancel()``
        returning True stops it (:class:`~solvers.errors.CancelledError`).

    Returns
    -------
    HistogramPropagationResult
        ``histograms`` ``(n, B)``, ``quantiles`` ``(n, m)``, ...

    Examples
    --------
    >>> import numpy as np
    >>> from solvers.domains import Graph
    >>> from solvers.histograms import make_bins, propagate_histograms
    >>> path = Graph(3, np.array([[0, 1], [1, 2]]))
    >>> bins = make_bins(lo=0.0, hi=1.0, count=4)
    >>> labels = np.array([[1.0, 0, 0, 0], [0, 0, 0, 1.0]])
    >>> result = propagate_histograms(path, [0, 2], labels, bins=bins)
    >>> result.histograms.shape
    (3, 4)
    >>> result.histograms[1].round(2)  # the middle node: the mass met half way
    array([0. , 0.5, 0.5, 0. ])
    """
    check_choice(method, ("wasserstein", "pdf"), "method")
    b = None if bins is None else make_bins(bins)
    if b is not None and b.periodic and method == "wasserstein":
        raise InputError("periodic bins live on the circle: use "
                         "solvers.histograms.circle.propagate_circular", field="bins.periodic")
    system = dirichlet_system(graph, labeled, laplacian=laplacian, linear_method=linear_method)
    nodes = np.asarray(labeled, dtype=np.int64)
    check_label_count(nodes, histograms, samples, densities)
    order = np.searchsorted(system.labeled, nodes)  # system rows are sorted node ids
    if method == "wasserstein":
        lev = quantile_levels(levels)
        q = label_quantiles(lev, bins=b, histograms=histograms, samples=samples,
                            densities=densities)
        V = np.empty_like(q)
        V[order] = q
        ext = harmonic_extension(system, V, rank_tol=rank_tol, tol=tol, max_iter=max_iter,
                                 progress=progress, should_cancel=should_cancel)
        Q = sort_rows(ext.values)  # in place; monotone already with non-negative weights
        H = None if b is None else histograms_from_inverse_cdf(Q, lev, b, sorted_rows=True)
    else:
        if b is None:
            raise InputError("method='pdf' needs bins", field="bins")
        h = label_histograms(b, histograms=histograms, samples=samples, densities=densities)
        V = np.empty_like(h)
        V[order] = h
        ext = harmonic_extension(system, V, rank_tol=rank_tol, tol=tol, max_iter=max_iter,
                                 progress=progress, should_cancel=should_cancel)
        H = np.clip(ext.values, 0.0, None, out=ext.values)
        H /= H.sum(axis=1, keepdims=True)
        Q, lev = None, None
    return HistogramPropagationResult(
        method=method, histograms=H, quantiles=Q, levels=lev, bins=b, labeled=nodes,
        rank=ext.rank, compression_error=ext.compression_error, linear_method=system.linear_method,
        iterations=ext.iterations, residual=ext.residual,
        converged=bool(ext.residual <= max(tol, 1e-8)))


def harmonic_means(graph, labeled, means, *, laplacian: str = "auto",
                   linear_method: str = "auto") -> np.ndarray:
    r"""Classical harmonic interpolation [ZGL03] of scalar labels.

    Minimizes :math:`\sum_{(u,v)} w_{uv} (f_u - f_v)^2` with :math:`f` fixed on the
    labeled nodes.

    Parameters
    ----------
    graph, labeled
        As in :func:`propagate_histograms`.
    means : (k,) array
        Their values.
    laplacian : {"auto", "robust", "cotan"}
        The Laplacian of a mesh (cotangent or robust); other domains have one.
    linear_method : {"auto", "direct", "amg"}
        Sparse Cholesky, or AMG-preconditioned CG.

    Returns
    -------
    (n,) array
    """
    system = dirichlet_system(graph, labeled, laplacian=laplacian, linear_method=linear_method)
    nodes = np.asarray(labeled, dtype=np.int64)
    v = np.asarray(means, dtype=np.float64).reshape(-1)
    if v.shape != (len(nodes),) or not np.all(np.isfinite(v)):
        raise InputError(f"means must be {len(nodes)} finite numbers", field="means")
    V = np.empty((len(nodes), 1))
    V[np.searchsorted(system.labeled, nodes), 0] = v
    return harmonic_extension(system, V).values[:, 0]
