r"""Chapter 5: semi-supervised learning of histograms on graphs (Wasserstein propagation).

Labels are histograms over a 1-D value axis (or the circle) at some nodes of a graph;
the unknown nodes get the distributions minimizing the Dirichlet energy in :math:`W_2`.

=====================  ================================================================
thesis                 module
=====================  ================================================================
§5.5 (discretization)  :mod:`.bins` — bin edges (``edges`` or ``lo/hi/count``, periodic),
                       histogram and sample validation
§5.3.1, §5.5           :mod:`.quantiles` — histograms / samples / piecewise-linear
                       densities ↔ inverse CDFs at ``m`` levels; back to histograms by
                       integrating over each bin
§5.2, §5.6             :mod:`.graphs` — graph weights (Graph, mesh cotangent or robust
                       Laplacian, point-cloud Laplacian, k-NN graph of coordinates)
Prop. 13               :mod:`.dirichlet` — one factorization of the reduced Laplacian,
                       one block solve for all levels (column compression)
Prop. 13–15, §5.2.2    :mod:`.propagation` — :func:`propagate_histograms` (Wasserstein
                       and PDF routes), :func:`harmonic_means` [ZGL03]
Prop. 16, §5.3.3       :mod:`.diffusion` — :func:`diffuse_histograms` (implicit heat steps
                       on inverse CDFs; PDF diffusion baseline)
§5.4                   :mod:`.circle` — :func:`propagate_circular`: S¹ / small metric
                       space LP (HiGHS), entropic route via Alg. 4 on a periodic 1-D grid
§5.6 (evaluation)      :mod:`.summaries` — mean, std, entropy, mode, circular mean/std,
                       W1 between histograms; :mod:`.features` — per-vertex histograms of
                       mean curvature / principal-direction angle over geodesic balls
                       (the curvatures: :mod:`solvers.curvature`)
=====================  ================================================================
"""

from solvers.histograms.bins import Bins, check_histograms, histogram_of_samples, make_bins
from solvers.histograms.circle import (
    CircularPropagationResult,
    circle_cost,
    dirichlet_value,
    propagate_circular,
)
from solvers.histograms.diffusion import HistogramDiffusionResult, diffuse_histograms
from solvers.histograms.dirichlet import check_labeled, dirichlet_system, harmonic_extension
from solvers.histograms.graphs import as_graph, graph_laplacian, knn_graph, laplacian_from_weights
from solvers.histograms.propagation import (
    HistogramPropagationResult,
    harmonic_means,
    label_histograms,
    label_quantiles,
    propagate_histograms,
)
from solvers.histograms.quantiles import (
    cdf_from_inverse_cdf,
    histograms_from_inverse_cdf,
    inverse_cdf_from_density,
    inverse_cdf_from_histograms,
    inverse_cdf_from_samples,
    quantile_levels,
)
from solvers.histograms.summaries import summarize, w1_distance

__all__ = [
    "Bins",
    "as_graph",
    "CircularPropagationResult",
    "HistogramDiffusionResult",
    "HistogramPropagationResult",
    "cdf_from_inverse_cdf",
    "check_histograms",
    "check_labeled",
    "circle_cost",
    "diffuse_histograms",
    "dirichlet_system",
    "dirichlet_value",
    "graph_laplacian",
    "harmonic_extension",
    "harmonic_means",
    "histogram_of_samples",
    "histograms_from_inverse_cdf",
    "inverse_cdf_from_density",
    "inverse_cdf_from_histograms",
    "inverse_cdf_from_samples",
    "knn_graph",
    "label_histograms",
    "label_quantiles",
    "laplacian_from_weights",
    "make_bins",
    "propagate_circular",
    "propagate_histograms",
    "quantile_levels",
    "summarize",
    "w1_distance",
]
