r"""Intrinsic point descriptors on triangle meshes (thesis §4.5.2, §3.7): HKS, WKS, landmarks.

Spectral descriptors come from the first ``k`` Laplace–Beltrami eigenpairs of the
generalized problem :math:`L \phi = \lambda A \phi` (``L`` the mesh's robust Laplacian,
``A`` the lumped vertex areas; eigenvectors :math:`A`-orthonormal), computed by scipy's
``eigsh`` in shift-invert mode and cached in ``mesh.operators``:

* heat kernel signature :math:`\mathrm{HKS}(x, t) = \sum_i e^{-\lambda_i t}\phi_i(x)^2`;
* wave kernel signature (Aubry et al. 2011, the descriptor the thesis uses)
  :math:`\mathrm{WKS}(x, e) = \sum_i \phi_i(x)^2 g_e(\lambda_i) / \sum_i g_e(\lambda_i)`,
  :math:`g_e(\lambda) = \exp(-(e - \log\lambda)^2 / 2\sigma^2)`, energies ``e`` log-spaced.

Landmark descriptors: for landmarks :math:`x_1..x_L`, the geodesic distance
:math:`d(x, x_l)` (potpourri3d's heat method) or the heat diffused from each landmark.
Meshes are at unit area, so the descriptors of two meshes are directly comparable.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from solvers.errors import InputError
from solvers.linalg import eigsh
from solvers.validation import check_choice, check_int, check_positive

LANDMARK_METHODS = ("geodesic", "heat")
# Eigenpairs solved for at least (the soft map's descriptor default), whatever k is asked.
EIGENPAIRS_SOLVED = 100


def eigenpairs(mesh, k: int) -> tuple[np.ndarray, np.ndarray]:
    r"""The ``k`` smallest pairs of :math:`L\phi = \lambda A \phi`.

    Eigenvectors are :math:`A`-orthonormal (:math:`\Phi^\top A \Phi = I`); the first is
    constant (:math:`\lambda_0 = 0` on a connected mesh).  Always solved for at least
    :data:`EIGENPAIRS_SOLVED` pairs and cached in ``mesh.operators`` per solved count, so
    the descriptors (``k`` 100) and ZoomOut (``k`` up to 80) share one solve and one cached
    basis; smaller ``k`` get the leading columns (views of the cache).

    Parameters
    ----------
    mesh : TriangleMesh
        A surface with ``n`` vertices.
    k : int
        Number of pairs.

    Returns
    -------
    evals : (k,) array
        Eigenvalues, increasing.
    evecs : (n, k) array
        Eigenvectors.
    """
    k = check_int(k, "k", low=2, high=max(2, mesh.n - 2))
    solved = max(k, min(EIGENPAIRS_SOLVED, mesh.n - 2))

    def build():
        A = sp.diags(mesh.areas)
        L = sp.csc_matrix(mesh.laplacian)
        # Shift-invert about a small negative sigma: L - sigma A is positive definite.
        sigma = -1e-3 * float(np.abs(L.diagonal()).mean() / np.mean(mesh.areas))
        vals, vecs = eigsh(L, k=solved, M=A.tocsc(), sigma=sigma, which="LM")
        order = np.argsort(vals)
        vals, vecs = np.maximum(vals[order], 0.0), vecs[:, order]
        vecs = vecs / np.sqrt(np.einsum("ij,i,ij->j", vecs, mesh.areas, vecs))
        return vals, vecs

    vals, vecs = mesh.operators.get(("softmaps.eigenpairs", solved, mesh.laplacian_kind),
                                    build)
    return vals[:k], vecs[:, :k]


def heat_kernel_signature(mesh, k: int = 100, times=None, n_times: int = 16) -> np.ndarray:
    r"""Heat kernel signature :math:`\mathrm{HKS}(x, t) = \sum_i e^{-\lambda_i t} \phi_i(x)^2`.

    Parameters
    ----------
    mesh : TriangleMesh
        The surface (``n`` vertices).
    k : int
        Eigenpairs used.
    times : (T,) array, optional
        Diffusion times; default log-spaced in
        :math:`[4\ln 10/\lambda_k, 4\ln 10/\lambda_1]`.
    n_times : int
        Number of default times.

    Returns
    -------
    (n, T) array
        One column per time.
    """
    vals, vecs = eigenpairs(mesh, k)
    if times is None:
        lo, hi = 4 * np.log(10) / vals[-1], 4 * np.log(10) / max(vals[1], 1e-12)
        times = np.geomspace(lo, hi, check_int(n_times, "n_times", low=1))
    times = np.asarray(times, dtype=np.float64)
    return (vecs**2) @ np.exp(-np.outer(vals, times))


def wks_energies(*spectra: np.ndarray, n_energies: int = 100) -> tuple[np.ndarray, float]:
    """Log-energies shared by several meshes' spectra (common range) and the WKS ``sigma``."""
    n_energies = check_int(n_energies, "n_energies", low=2)
    lo = max(np.log(max(s[1], 1e-12)) for s in spectra)
    hi = min(np.log(max(s[-1], 1e-12)) for s in spectra)
    if hi <= lo:
        raise InputError("the spectra share no energy range", field="k")
    sigma = 7.0 * (hi - lo) / n_energies
    energies = np.linspace(lo + 2 * sigma, hi - 2 * sigma, n_energies)
    return energies, sigma


def wave_kernel_signature(mesh, k: int = 100, energies=None, sigma: float | None = None,
                          n_energies: int = 100) -> np.ndarray:
    """Wave kernel signature (Aubry et al. 2011), each column of unit area-weighted mean.

    Parameters
    ----------
    mesh, k : TriangleMesh, int
        The surface (``n`` vertices) and the eigenpairs used.
    energies : (E,) array, optional
        Log-eigenvalue energies (default :func:`wks_energies` of this mesh alone); pass the
        energies of :func:`wks_energies` of both meshes to compare two meshes.
    sigma : float, optional
        Width of the Gaussian energy filters (default: that of :func:`wks_energies`, or
        7 times the range of ``energies`` over their count).
    n_energies : int
        Number of default energies.

    Returns
    -------
    (n, E) array
    """
    vals, vecs = eigenpairs(mesh, k)
    if energies is None:
        energies, sigma = wks_energies(vals, n_energies=n_energies)
    energies = np.asarray(energies, dtype=np.float64)
    sigma = check_positive(sigma if sigma is not None else 7.0 * np.ptp(energies)
                           / max(len(energies), 1), "sigma")
    logs = np.log(np.maximum(vals[1:], 1e-12))
    g = np.exp(-((energies[None, :] - logs[:, None]) ** 2) / (2 * sigma**2))
    g = g / np.maximum(g.sum(axis=0), 1e-300)
    wks = (vecs[:, 1:] ** 2) @ g
    return wks / np.maximum(mesh.areas @ wks, 1e-300)


def check_landmarks(landmarks, n: int, field: str = "landmarks") -> np.ndarray:
    """``(L,)`` int64 vertex indices in ``[0, n)``, no repeats."""
    try:
        x = np.asarray(landmarks if len(landmarks) else np.zeros(0, np.int64))
    except TypeError as exc:
        raise InputError(f"{field} must be a list of vertex indices", field=field) from exc
    if x.ndim != 1 or (len(x) and not np.issubdtype(x.dtype, np.integer)):
        raise InputError(f"{field} must be a list of integer vertex indices", field=field)
    x = x.astype(np.int64)
    bad = np.flatnonzero((x < 0) | (x >= n))
    if len(bad):
        raise InputError(f"{field}[{int(bad[0])}] = {int(x[bad[0]])} is outside [0, {n - 1}]",
                         field=field)
    if len(np.unique(x)) != len(x):
        raise InputError(f"{field} repeats a vertex", field=field)
    return x


def geodesic_distances_from(mesh, sources) -> np.ndarray:
    """``(n, len(sources))`` heat-method geodesic distances (potpourri3d).

    The solver is built per call and not cached: it holds ~3 KB per vertex (22 MB on a
    7,207-vertex mesh, more than a soft map's coarse rows); :func:`landmark_descriptors`
    caches its distance columns instead."""
    import potpourri3d as pp3d

    sources = check_landmarks(sources, mesh.n, "sources")
    if len(sources) == 0:
        return np.zeros((mesh.n, 0))
    solver = pp3d.MeshHeatMethodDistanceSolver(np.ascontiguousarray(mesh.vertices),
                                               np.ascontiguousarray(mesh.faces))
    return np.stack([solver.compute_distance(int(s)) for s in sources], axis=1)


def landmark_descriptors(mesh, landmarks, *, method: str = "geodesic",
                         t: float | None = None) -> np.ndarray:
    r"""Descriptors from landmarks: geodesic distance or diffused heat.

    Parameters
    ----------
    mesh : TriangleMesh
        The surface (``n`` vertices).
    landmarks : (L,) int array
        Landmark vertices :math:`x_l`.
    method : {"geodesic", "heat"}
        ``"geodesic"``: :math:`d(x, x_l)` (heat method); ``"heat"``: the density
        :math:`H_t \delta_{x_l}` at time ``t``, normalized by its maximum so each landmark
        weighs the same.
    t : float, optional
        Heat time of ``method="heat"`` (default ``0.01``, unit-area units).

    Returns
    -------
    (n, L) array
    """
    landmarks = check_landmarks(landmarks, mesh.n)
    check_choice(method, LANDMARK_METHODS, "method")
    if method == "geodesic":
        def build():
            d = geodesic_distances_from(mesh, landmarks)
            d.setflags(write=False)  # cached: shared by later calls
            return d

        return mesh.operators.get(("softmaps.landmark_geodesics", tuple(landmarks.tolist())),
                                  build)
    t = 0.01 if t is None else check_positive(t, "t")
    deltas = np.zeros((mesh.n, len(landmarks)))
    deltas[landmarks, np.arange(len(landmarks))] = 1.0 / mesh.areas[landmarks]
    heat = mesh.heat_kernel(t, 1).apply(deltas)
    return heat / np.maximum(heat.max(axis=0), 1e-300)
