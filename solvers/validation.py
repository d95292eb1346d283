r"""The only validators of solver inputs: distributions, weights, scalars, graph edges.

The library's solvers and the service's submission checks call these same functions, so a
request accepted at the door passes the worker's checks too. Each raises
:class:`~solvers.errors.InputError` naming the offending ``field``.

Conventions used by every solver: a distribution is given either as
*masses* ``m`` (per point, summing to 1) or as a *density* ``mu`` with
respect to the area weights, ``m = a * mu`` and :math:`a^\top \mu = 1`.
"""

from __future__ import annotations

import math

import numpy as np

from solvers.errors import InputError


def check_masses(values, n: int, field: str = "masses") -> np.ndarray:
    """Return ``values`` as a float ``(n,)`` or ``(n, k)`` array; finite, non-negative, non-zero.

    Finite values whose sum overflows (e.g. ``[1.7e308, 1.7e308]``) are valid: normalize
    them with :func:`normalized_columns`, never by dividing by ``x.sum()`` (which is inf).
    Raises ``InputError`` naming ``field`` otherwise.

    Parameters
    ----------
    values, n, field : array, int, str
        ``(n,)`` or ``(n, k)`` masses, the number of points, and the input an error names.

    Returns
    -------
    (n,) or (n, k) float array
    """
    try:
        x = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(f"{field} must be numeric: a list of numbers (or an (n, k) block)",
                         field=field) from exc
    if x.ndim not in (1, 2) or x.shape[0] != n:
        raise InputError(f"{field} must have length {n} (one value per point), got shape "
                         f"{x.shape}", field=field)
    if not np.all(np.isfinite(x)):
        bad = int(np.argwhere(~np.isfinite(x))[0, 0])
        raise InputError(f"{field}[{bad}] is NaN or infinite", field=field)
    if np.any(x < 0):
        bad = int(np.argwhere(x < 0)[0, 0])
        raise InputError(f"{field}[{bad}] is negative ({x.flat[np.argmax(x < 0)]:g})",
                         field=field)
    if n == 0 or np.any(x.max(axis=0) <= 0):
        raise InputError(f"{field} has zero total mass", field=field)
    return x


def mass_totals(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(peak, relative)`` per column of checked masses, their total being ``peak *
    relative``: ``(1, x.sum())`` where that sum is a finite normal float (the plain sum's
    bits), else the largest value and the sum of the values divided by it, so that the total
    neither overflows (finite values near 1.7e308) nor loses subnormals' digits (5e-324).

    Parameters
    ----------
    x : (n,) or (n, k) array
        Masses checked by :func:`check_masses`.

    Returns
    -------
    peak, relative : array
        Per column; the total is ``peak * relative``.
    """
    with np.errstate(over="ignore"):  # an overflowing sum takes the scaled path below
        plain = x.sum(axis=0)
    exact = np.isfinite(plain) & (plain >= np.finfo(np.float64).tiny)
    if np.all(exact):
        return np.ones_like(plain), plain
    peak = x.max(axis=0)
    with np.errstate(over="ignore"):
        scaled = (x / peak).sum(axis=0)
    return np.where(exact, 1.0, peak), np.where(exact, plain, scaled)


def normalized_columns(x: np.ndarray) -> np.ndarray:
    """Checked masses (:func:`check_masses`) rescaled to sum to 1 per column; the scaling
    by the largest value first keeps every finite input finite and non-zero.

    Parameters
    ----------
    x : (n,) or (n, k) array
        Checked masses.

    Returns
    -------
    (n,) or (n, k) array summing to 1 per column
    """
    peak, relative = mass_totals(x)
    return (x / peak) / relative


def normalize_masses(values, n: int, field: str = "masses") -> np.ndarray:
    """Validated masses rescaled to sum to 1 (per column).

    Parameters
    ----------
    values, n, field : array, int, str
        As in :func:`check_masses`.

    Returns
    -------
    (n,) or (n, k) array
        Columns summing to 1.
    """
    return normalized_columns(check_masses(values, n, field))


def density_from_masses(masses: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """Density ``mu = m / a`` (per column), so that ``a @ mu == m.sum()``.

    Parameters
    ----------
    masses, areas : array
        Masses ``(n,)`` or ``(n, k)``; area weights ``(n,)``.

    Returns
    -------
    (n,) or (n, k) array
    """
    a = areas if masses.ndim == 1 else areas[:, None]
    return masses / a


def masses_from_density(density: np.ndarray, areas: np.ndarray) -> np.ndarray:
    """Masses ``m = a * mu`` of a density (per column), the inverse of :func:`density_from_masses`.

    Parameters
    ----------
    density, areas : array
        Density ``(n,)`` or ``(n, k)``; its area weights ``(n,)``.

    Returns
    -------
    (n,) or (n, k) array
    """
    a = areas if density.ndim == 1 else areas[:, None]
    return density * a


def check_weights(weights, k: int, field: str = "weights") -> np.ndarray:
    """Barycentric weights: ``(k,)`` finite, non-negative, with a positive finite sum;
    normalized to 1.

    ``None`` gives uniform weights. Finite values near the float limit can sum to inf
    (which would normalize to zeros): refused, naming ``field``.

    Parameters
    ----------
    weights, k, field : array or None, int, str
        ``(k,)`` weights (None: uniform), their count, and the input an error names.

    Returns
    -------
    (k,) array summing to 1
    """
    if weights is None:
        return np.full(k, 1.0 / k)
    try:
        w = np.asarray(weights, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:  # an int beyond the float range
        raise InputError(f"{field} must be numbers", field=field) from exc
    if w.shape != (k,):
        raise InputError(f"{field} must have one value per distribution ({k}), got shape "
                         f"{w.shape}", field=field)
    with np.errstate(over="ignore", invalid="ignore"):
        total = w.sum()
    if not np.all(np.isfinite(w)) or np.any(w < 0) or total <= 0:
        raise InputError(f"{field} must be finite, non-negative, with a positive sum",
                         field=field)
    if not np.isfinite(total):
        raise InputError(f"{field} sums beyond the float range; scale it down", field=field)
    return w / total


def check_positive(value, field: str) -> float:
    """A finite number > 0.

    Parameters
    ----------
    value, field : float, str
        The number and the input an error names.

    Returns
    -------
    float
    """
    try:
        x = float(value)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(f"{field} must be a number", field=field) from exc
    if not (math.isfinite(x) and x > 0):
        raise InputError(f"{field} must be positive and finite, got {value}", field=field)
    return x


def check_finite(value, field: str) -> float:
    """A finite number (any sign).

    Parameters
    ----------
    value, field : float, str
        As in :func:`check_positive`.

    Returns
    -------
    float
        The value.
    """
    try:
        x = float(value)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(f"{field} must be a number", field=field) from exc
    if not math.isfinite(x):
        raise InputError(f"{field} must be finite, got {value}", field=field)
    return x


def check_int(value, field: str, *, low: int | None = None, high: int | None = None) -> int:
    """An integer in ``[low, high]`` (bounds optional).

    Parameters
    ----------
    value, field, low, high : int, str, int or None, int or None
        The number, the input an error names, and the inclusive bounds.

    Returns
    -------
    int
    """
    if isinstance(value, bool):
        raise InputError(f"{field} must be an integer", field=field)
    try:
        x = int(value)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(f"{field} must be an integer", field=field) from exc
    if x != value:
        raise InputError(f"{field} must be an integer, got {value}", field=field)
    if low is not None and x < low:
        raise InputError(f"{field} must be >= {low}, got {x}", field=field)
    if high is not None and x > high:
        raise InputError(f"{field} must be <= {high}, got {x}", field=field)
    return x


def check_edges(edges, n: int, field: str = "edges") -> np.ndarray:
    """``(m, 2)`` int64 node pairs with endpoints in ``[0, n)`` and no self-loops.

    Values beyond int64 or non-integers are refused before any conversion can overflow.

    Parameters
    ----------
    edges, n, field : array, int, str
        ``(m, 2)`` node pairs, the node count, the input an error names.

    Returns
    -------
    (m, 2) int64 array
    """
    e = _integer_array(edges, field, "a list of node pairs")
    if e.size == 0:
        e = e.reshape(0, 2)
    if e.ndim != 2 or e.shape[1] != 2:
        raise InputError(f"{field} must be a list of node pairs (m, 2), got shape {e.shape}",
                         field=field)
    outside = np.flatnonzero(((e < 0) | (e >= n)).any(axis=1))
    if len(outside):
        i = int(outside[0])
        raise InputError(f"{field}[{i}] = {e[i].tolist()} has an endpoint outside "
                         f"[0, {n - 1}]", field=field)
    out = e.astype(np.int64)
    loops = np.flatnonzero(out[:, 0] == out[:, 1])
    if len(loops):
        raise InputError(f"{field}[{int(loops[0])}] is a self-loop", field=field)
    return out


def _integer_array(values, field: str, what: str) -> np.ndarray:
    """``values`` as an integer array (int64, or object holding Python ints beyond int64,
    which the caller's range check then refuses), never silently truncated or wrapped."""
    try:
        x = np.asarray(values)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(f"{field} must be {what} (a rectangular array of integers)",
                         field=field) from exc
    if x.size == 0:
        return np.zeros(x.shape, dtype=np.int64)
    if x.dtype == bool:
        raise InputError(f"{field} must hold integers, not booleans", field=field)
    if np.issubdtype(x.dtype, np.integer):
        if x.dtype == np.uint64 and int(x.max()) > np.iinfo(np.int64).max:
            return x.astype(object)
        return x.astype(np.int64, copy=False)
    if np.issubdtype(x.dtype, np.floating):
        if not np.all(np.isfinite(x)) or np.any(np.mod(x, 1) != 0):
            raise InputError(f"{field} must hold integers", field=field)
        if np.any(np.abs(x) > 2.0**62):
            return x.astype(object)
        return x.astype(np.int64)
    if x.dtype == object:
        flat = x.ravel()
        for i, v in enumerate(flat):
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise InputError(f"{field} must be {what} of integers; found {type(v).__name__}"
                                 f" at flat position {i}", field=field)
        return x
    raise InputError(f"{field} must be {what} (integers)", field=field)


def check_edge_weights(weights, m: int, field: str = "edge_weights") -> np.ndarray:
    """``(m,)`` positive finite weights, one per edge (``None``: all ones).

    Parameters
    ----------
    weights, m, field : array or None, int, str
        One weight per edge (None: ones), the edge count, the input an error names.

    Returns
    -------
    (m,) float array
    """
    if weights is None:
        return np.ones(m)
    try:
        w = np.asarray(weights, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(f"{field} must be numbers", field=field) from exc
    if w.shape != (m,):
        raise InputError(f"{field} must have one value per edge ({m}), got shape {w.shape}",
                         field=field)
    bad = np.flatnonzero(~(np.isfinite(w) & (w > 0)))
    if len(bad):
        raise InputError(f"{field}[{int(bad[0])}] must be positive and finite, got "
                         f"{w[bad[0]]:g}", field=field)
    return w


def check_node_indices(nodes, n: int, field: str = "nodes") -> np.ndarray:
    """``(k,)`` distinct int64 node indices in ``[0, n)``, ``k >= 1``.

    Parameters
    ----------
    nodes, n, field : array, int, str
        Node indices, how many nodes the graph has, and the input an error names.

    Returns
    -------
    (k,) int64 array of distinct indices
    """
    try:
        raw = np.asarray(nodes, dtype=object).ravel()
    except (TypeError, ValueError) as exc:
        raise InputError(f"{field} must be a list of node indices", field=field) from exc
    if raw.size == 0:
        raise InputError(f"{field} needs at least one node", field=field)
    for i, v in enumerate(raw):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 0 <= v < n:
            raise InputError(f"{field}[{i}] = {v!r} is not a node index in [0, {n - 1}]",
                             field=field)
    out = raw.astype(np.int64)
    uniq, first, counts = np.unique(out, return_index=True, return_counts=True)
    if np.any(counts > 1):
        dup = int(uniq[np.argmax(counts > 1)])
        raise InputError(f"{field} lists node {dup} more than once", field=field)
    return out


def check_anchored_components(component_labels, nodes, field: str = "nodes") -> None:
    """Every connected component (``component_labels``, ``(n,)``) holds one of ``nodes``.

    The Dirichlet problems of propagation (harmonic extension from given nodes) are
    singular on a component without a given node; the error names that component.

    Parameters
    ----------
    component_labels, nodes, field : array, array, str
        Component of every point ``(n,)``, the given nodes ``(k,)``, the input an error
        names.
    """
    labels = np.asarray(component_labels)
    count = int(labels.max()) + 1 if len(labels) else 0
    have = np.zeros(count, dtype=bool)
    have[labels[np.asarray(nodes, dtype=np.int64)]] = True
    if not have.all():
        comp = int(np.flatnonzero(~have)[0])
        members = np.flatnonzero(labels == comp)
        raise InputError(
            f"connected component {comp} ({len(members)} nodes, e.g. node {int(members[0])}) "
            f"has no node in {field}; give at least one per component ({count} components)",
            field=field)


def check_indices(indices, n: int, field: str = "indices") -> np.ndarray:
    """``(k,)`` int64 point indices in ``[0, n)`` (values beyond int64 refused, not wrapped).

    Parameters
    ----------
    indices, n, field : array, int, str
        Point indices ``(k,)``; points of the domain; the input an error names.

    Returns
    -------
    (k,) int64 array
    """
    idx = _integer_array(indices, field, "a list of point indices")
    if idx.ndim != 1:
        raise InputError(f"{field} must be a flat list of point indices, got shape {idx.shape}",
                         field=field)
    outside = np.flatnonzero((idx < 0) | (idx >= n))
    if len(outside):
        raise InputError(f"{field}[{int(outside[0])}] = {idx[outside[0]]} is outside "
                         f"[0, {n - 1}]", field=field)
    return idx.astype(np.int64)


# Mass that distributions of one problem may put differently on a connected component
# (L1 over components): the one tolerance of the library and the service's submission check.
COMPONENT_MASS_TOL = 1e-9


def check_component_masses(labels: np.ndarray, masses: np.ndarray, field: str,
                           tol: float = COMPONENT_MASS_TOL) -> None:
    """Refuse ``(n, k)`` masses whose columns put different mass on some component.

    ``labels`` ``(n,)``: connected component of every point. Transport never moves mass
    between components, so every column must give each component the same total (L1 gap
    over components at most ``tol``, mass units). Raises ``UnsupportedDomainError``.

    Parameters
    ----------
    labels, masses, field, tol : array, array, str, float
        Component of every point ``(n,)``, distributions ``(n, k)``, the input an error
        names, and the largest L1 gap over components (mass units).
    """
    from solvers.errors import UnsupportedDomainError

    labels = np.asarray(labels)
    count = int(labels.max()) + 1 if len(labels) else 1
    if count <= 1 or masses.ndim != 2 or masses.shape[1] < 2:
        return
    per = np.stack([np.bincount(labels, weights=masses[:, j], minlength=count)
                    for j in range(masses.shape[1])], axis=1)
    gap = np.abs(per - per[:, :1]).sum(axis=0)
    if np.any(gap > tol):
        j = int(np.argmax(gap))
        raise UnsupportedDomainError(
            f"the domain has {count} connected components and mass cannot move between "
            f"them, but the distributions put different mass on them (component masses "
            f"{np.round(per[:, 0], 6).tolist()} vs {np.round(per[:, j], 6).tolist()}, L1 gap "
            f"{gap[j]:.3g} > {tol:g}); give each component the same mass in every "
            "distribution", field=field)


# Largest regularization accepted, as a multiple of the squared domain extent: beyond it the
# heat kernel is uniform over the domain (nothing left to transport) and D_a + tL is too
# ill-conditioned to factor.
GAMMA_MAX_FACTOR = 100.0
GAMMA_MIN = 1e-300  # below it the heat time gamma/4 underflows (subnormals) to 0


def gamma_max(extent: float) -> float:
    """The largest regularization :func:`check_gamma` admits on a domain of this extent.

    Parameters
    ----------
    extent : float
        The domain's extent (``Domain.extent``).

    Returns
    -------
    float
    """
    return GAMMA_MAX_FACTOR * float(extent) ** 2


def check_gamma(gamma, extent: float, field: str = "gamma") -> float:
    """A regularization ``GAMMA_MIN <= gamma <= GAMMA_MAX_FACTOR * extent**2`` (finite).

    ``extent``: the domain's size in its own units (``Domain.extent``: bounding-box
    diagonal at unit area, grid diagonal, graph node count in hops).

    Parameters
    ----------
    gamma, extent, field : float, float, str
        The regularization, the domain's extent, the input an error names.

    Returns
    -------
    float
        ``gamma``.
    """
    g = check_positive(gamma, field)
    if g < GAMMA_MIN:
        raise InputError(f"{field} = {g:g} is below {GAMMA_MIN:g} (its heat time would "
                         "underflow to 0)", field=field)
    top = gamma_max(extent)
    if g > top:
        raise InputError(f"{field} = {g:g} is beyond {top:.3g} ({GAMMA_MAX_FACTOR:g} x the "
                         f"squared domain extent {float(extent):.3g}): the heat kernel would be "
                         "uniform over the domain; use a smaller value", field=field)
    return g


# Smallest regularization a domain resolves, as a fraction of its squared length scale h:
# the Gibbs weight exp(-h^2 / gamma) between neighbouring points must stay above machine
# epsilon relative to a point's own weight, i.e. gamma >= h^2 / ln(1 / eps) (~ h^2 / 36);
# below it the kernel is the identity in floating point, no mass moves between neighbours and
# Sinkhorn either stagnates or "converges" to a value that only scales with gamma.
GAMMA_RESOLUTION = 1.0 / math.log(1.0 / float(np.finfo(np.float64).eps))


def check_gamma_resolved(gamma, h: float, field: str = "gamma") -> float:
    """A regularization the domain resolves: ``gamma >= GAMMA_RESOLUTION * h**2``.

    ``h``: the domain's length scale (``DomainSketch.length_scale``: mean edge length on
    meshes, grid spacing, one hop on graphs, ``sqrt(1/n)`` on point clouds at unit area).

    Parameters
    ----------
    gamma, h, field : float, float, str
        Regularization; the domain's length scale; the input an error names.

    Returns
    -------
    float
        ``gamma``, once resolved.
    """
    g = check_positive(gamma, field)
    low = GAMMA_RESOLUTION * float(h) ** 2
    if g < low:
        raise InputError(f"{field} = {g:g} is below {low:.3g}, the smallest regularization "
                         f"this domain can resolve (h^2 / {1.0 / GAMMA_RESOLUTION:.1f} with "
                         f"length scale h = {float(h):.3g}): the kernel between neighbouring "
                         "points would underflow and no mass could move", field=field)
    return g


def check_entropy_bound(bound, areas: np.ndarray, field: str = "entropy_bound") -> float:
    r"""An entropy bound :math:`H_0` reachable by sharpening: finite and at least
    :math:`\log \min_i a_i`, the entropy of the most concentrated distribution (a point
    mass on the smallest cell); entropies are at most 0 (uniform density on unit area).

    Parameters
    ----------
    bound, areas, field : float, (n,) array, str
        The bound :math:`H_0`, the area weights, the input an error names.

    Returns
    -------
    float
    """
    h = check_finite(bound, field)
    low = float(np.log(np.min(areas)))
    if h < low:
        raise InputError(f"{field} = {h:g} is below {low:.6g}, the entropy of a point mass on "
                         "this domain (log of the smallest area weight): no distribution "
                         "reaches it", field=field)
    return h


def check_anchored(n_nodes: int, edges: np.ndarray, anchors, field: str = "edges") -> None:
    """Every node of the graph ``(n_nodes, edges)`` is connected to some anchor node.

    Parameters
    ----------
    n_nodes, edges, anchors, field : int, (m, 2) array, array, str
        The graph, its anchor nodes, and the input an error names.
    """
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    graph = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n_nodes, n_nodes))
    _, labels = connected_components(graph, directed=False)
    anchored = np.zeros(int(labels.max()) + 1, dtype=bool)
    anchored[labels[np.asarray(list(anchors), dtype=np.int64)]] = True
    lost = np.flatnonzero(~anchored[labels])
    if len(lost):
        raise InputError(f"node {int(lost[0])} is not connected to any fixed node "
                         f"({len(lost)} such nodes)", field=field)


def check_size(shape, limit: int, field: str = "shape") -> int:
    """The number of points ``prod(shape)`` as a Python int (no int64 wrap-around),
    refused when above ``limit``.

    Parameters
    ----------
    shape, limit, field : sequence of int, int, str
        Points per axis, the largest number of points, the input an error names.

    Returns
    -------
    int
        ``prod(shape)``.
    """
    try:
        dims = [int(s) for s in shape]
    except (TypeError, ValueError, OverflowError) as exc:
        raise InputError(f"{field} must be a list of integers", field=field) from exc
    total = math.prod(max(d, 0) for d in dims)
    if total > limit:
        raise InputError(f"{field} {dims} gives {total} points, more than the limit of {limit}",
                         field=field)
    return total


def check_cost_matrix(cost, field: str = "cost", *, max_size: int | None = None) -> np.ndarray:
    """``(B, B)`` ground cost of a small metric space: finite, non-negative, symmetric (to
    1e-12 of its largest entry; the exact mean is returned) with a zero diagonal, ``B >= 2``.

    Symmetry and a zero diagonal make a transport cost between histograms on the space
    independent of direction and zero between equal histograms.

    Parameters
    ----------
    cost, field, max_size : (B, B) array, str, int or None
        The ground cost, the input an error names, and the largest ``B``.

    Returns
    -------
    (B, B) array
    """
    try:
        c = np.asarray(cost, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{field} must be a square matrix of numbers", field=field) from exc
    if c.ndim != 2 or c.shape[0] != c.shape[1] or c.shape[0] < 2:
        raise InputError(f"{field} must be a square matrix of at least 2 x 2, got shape "
                         f"{c.shape}", field=field)
    if max_size is not None and c.shape[0] > max_size:
        raise InputError(f"{field} has {c.shape[0]} points, more than {max_size}", field=field)
    if not np.all(np.isfinite(c)) or np.any(c < 0):
        raise InputError(f"{field} must be finite and non-negative", field=field)
    if np.any(np.diag(c) != 0):
        raise InputError(f"{field} must have a zero diagonal (a point is at distance 0 from "
                         "itself)", field=field)
    scale = float(c.max())
    if np.abs(c - c.T).max() > 1e-12 * max(scale, 1e-300):
        i, j = (int(v) for v in np.unravel_index(np.argmax(np.abs(c - c.T)), c.shape))
        raise InputError(f"{field} must be symmetric: {field}[{i}][{j}] != {field}[{j}][{i}]",
                         field=field)
    return 0.5 * (c + c.T)


def masses_block(domain, values, field: str, columns: int | None = None) -> np.ndarray:
    """Validated, normalized ``(n,)`` or ``(n, k)`` masses.

    Parameters
    ----------
    domain : domain
        Gives the node count ``n``.
    values : array_like
        ``(n,)`` or ``(n, k)`` non-negative masses.
    field : str
        The input's name, for errors.
    columns : int, optional
        The ``k`` required (a 2-D block of that many columns).

    Returns
    -------
    ndarray
        The masses, each column normalized to total 1.
    """
    m = normalize_masses(values, domain.n, field)
    if columns is not None and (m.ndim != 2 or m.shape[1] != columns):
        raise InputError(f"{field} must have shape ({domain.n}, {columns})", field=field)
    return m


def distribution_pair(domain, mu0, mu1) -> tuple[np.ndarray, np.ndarray]:
    """Validated, normalized ``(n,)`` masses ``mu0``, ``mu1`` (one distribution each).

    Parameters
    ----------
    domain : domain
        Gives the node count ``n``.
    mu0, mu1 : array_like
        ``(n,)`` non-negative masses.

    Returns
    -------
    tuple of ndarray
        ``(m0, m1)``, each normalized to total 1.
    """
    pair = []
    for name, values in (("mu0", mu0), ("mu1", mu1)):
        m = masses_block(domain, values, name)
        if m.ndim != 1:
            raise InputError(f"{name} must be one distribution of shape ({domain.n},)",
                             field=name)
        pair.append(m)
    return pair[0], pair[1]


def check_components(domain, masses: np.ndarray, tol: float, field: str) -> None:
    """Refuse inputs whose per-component masses differ (mass cannot cross components).

    With matching component masses the heat kernel is block diagonal and the solvers work
    on every component at once.

    Parameters
    ----------
    domain : domain
        The domain whose connected components are compared.
    masses : ndarray
        ``(n, k)`` masses, one distribution per column.
    tol : float
        Largest difference of a component's masses between columns.
    field : str
        The input's name, for the error.
    """
    domain.require_matching_component_masses(masses, tol, field)


def check_choice(value, choices, field: str) -> str:
    """``value`` if it is one of ``choices``, else an :class:`InputError` naming ``field``.

    Parameters
    ----------
    value : str
        The given choice.
    choices : sequence of str
        The allowed ones.
    field : str
        The input's name, for the error.

    Returns
    -------
    str
    """
    if value not in choices:
        raise InputError(f"{field} must be one of {', '.join(map(repr, choices))}, got "
                         f"{value!r}", field=field)
    return value
