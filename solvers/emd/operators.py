r"""Per-mesh operators for the Beckmann (W1) problem, built once and cached on the mesh.

Discretization (thesis §2.3, Solomon et al. 2014): distributions are vertex
masses ``m`` (``m = a ⊙ ρ``), flows are piecewise-constant tangent vector
fields ``J`` stored as ``(F, 3)`` arrays, and the divergence is the weak one of
the foundation, ``D = mesh.divergence = -Gᵀ diag(A_f)``, so that

* the particular flow of eq. 2.4 is ``v = ∇f`` with ``L f = m1 - m0``
  (``L = GᵀAG`` the cotangent Laplacian), and ``D v = m0 - m1``;
* the divergence-free ("curl") fields are rotated gradients ``ψ = N × ∇s`` of
  piecewise-linear stream functions ``s`` (eq. 2.5), which must be constant on
  every boundary loop so that no mass leaks through the boundary;
* on surfaces with handles (genus > 0) the ``2g`` harmonic fields complete the
  basis (the Hodge decomposition); without them W1 is overestimated.

The stream functions are parametrized as ``s = P c`` with ``P`` (V × n_c):
one hat function per interior vertex (minus one pinned vertex per closed
component) plus one indicator per boundary loop (minus one loop per component
with boundary).  ``K = Pᵀ L P`` is then symmetric positive definite; it is the
matrix of the ADMM c-update (Fig. 2.5) and is factored once per mesh.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from solvers.emd.interior_point import flow_structure
from solvers.errors import UnsupportedDomainError
from solvers.linalg import eigsh, factorize_spd


def mesh_operators(mesh) -> EMDOperators:
    """The :class:`EMDOperators` of ``mesh``, built on first use and kept in its operator
    store (its lazily built parts are entries of the same store).

    Parameters
    ----------
    mesh : TriangleMesh
        The surface.

    Returns
    -------
    EMDOperators
    """
    return mesh.operators.get("emd", lambda: EMDOperators(mesh))


def _first_per_label(labels: np.ndarray, count: int) -> np.ndarray:
    first = np.full(count, -1, dtype=np.int64)
    order = np.arange(len(labels))[::-1]
    first[labels[order]] = order  # last write wins: the smallest index
    return first


class EMDOperators:
    """Gradient, rotation, pinned Poisson solver and curl-basis system of one mesh.

    Parameters
    ----------
    mesh : TriangleMesh
        The surface (``V`` vertices, ``F`` faces).
    """

    def __init__(self, mesh):
        self.mesh = mesh
        self.n_vertices = mesh.n
        self.n_faces = mesh.n_faces
        self.face_areas = np.asarray(mesh.face_areas)
        self.normals = np.asarray(mesh.face_normals)
        self.gradient_matrix = mesh.gradient.tocsr()
        self.laplacian = mesh.cotan_laplacian.tocsr()
        self.n_components = mesh.n_components
        self.labels = mesh.component_labels
        self.pins = _first_per_label(self.labels, self.n_components)
        keep = np.ones(self.n_vertices, dtype=bool)
        keep[self.pins] = False
        self._keep = np.flatnonzero(keep)
        self._poisson = factorize_spd(self.laplacian[self._keep][:, self._keep])
        # Parts built on demand are entries of the mesh's operator store (built once under
        # its lock, each measured): ("emd", "stream"), ("emd", "curl_factor"), ...
        self._store = mesh.operators

    # -- fields -------------------------------------------------------------
    def grad(self, f: np.ndarray) -> np.ndarray:
        """Per-face gradient of vertex function(s): (V,) -> (F, 3); (V, k) -> (F, 3, k).

        Parameters
        ----------
        f : (V,) or (V, k) array
            Vertex function(s).
        """
        g = self.gradient_matrix @ f
        return g.reshape(self.n_faces, 3, *f.shape[1:])

    def grad_adjoint(self, field: np.ndarray) -> np.ndarray:
        """``Gᵀ diag(A) field`` for a (F, 3) field, i.e. ``-D field`` (V,).

        Parameters
        ----------
        field : (F, 3) array
            A face field.
        """
        return self.gradient_matrix.T @ (self.face_areas[:, None] * field).ravel()

    def inner(self, x: np.ndarray, y: np.ndarray) -> float:
        """Area-weighted inner product of two (F, 3) fields.

        Parameters
        ----------
        x, y : (F, 3) array
            Face fields.
        """
        return float(np.einsum("f,fc,fc->", self.face_areas, x, y))

    def norm(self, x: np.ndarray) -> float:
        """Area-weighted L2 norm of an (F, 3) field.

        Parameters
        ----------
        x : (F, 3) array
            A face field.
        """
        return float(np.sqrt(max(self.inner(x, x), 0.0)))

    def weak_divergence(self, field: np.ndarray) -> np.ndarray:
        """``D field`` (V,): the integral of ``div field`` against each hat function.

        Parameters
        ----------
        field : (F, 3) array
            A face field.
        """
        return -self.grad_adjoint(field)

    # -- Poisson ------------------------------------------------------------
    def solve_poisson(self, rhs: np.ndarray) -> np.ndarray:
        """Solve ``L f = rhs`` (rhs summing to zero on every component), pinning one
        vertex per component to 0: the constant null space of the Neumann problem.

        Parameters
        ----------
        rhs : (V,) array
            Right-hand side, summing to zero on every component.
        """
        out = np.zeros(rhs.shape, dtype=np.float64)
        out[self._keep] = self._poisson.solve(np.ascontiguousarray(rhs[self._keep]))
        return out

    def particular_flow(self, difference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(f, v = ∇f)`` with ``L f = difference`` (= m1 - m0), eq. 2.4.

        Parameters
        ----------
        difference : (V,) array
            ``m1 - m0``.
        """
        f = self.solve_poisson(difference)
        return f, self.grad(f)

    @property
    def has_green_matrix(self) -> bool:
        return ("emd", "green") in self._store

    def green_matrix(self, check=None, max_vertices: int | None = None):
        """The dense Green's matrix ``L⁺`` (float32 panels,
        :class:`solvers.emd.green_panels.GreenMatrix`), built on first use (``V`` unit
        solves with the pinned factor) and kept; ``4 V²`` bytes.
        Concurrent jobs on a cached mesh share one build (the store's lock).

        Parameters
        ----------
        check : callable, optional
            Called between solve blocks of the build (cancellation).
        max_vertices : int, optional
            Largest mesh for the dense matrix (default ``GREEN_MAX_VERTICES``).
        """
        from solvers.emd.green import build_green_matrix

        return self._store.get(("emd", "green"), lambda: build_green_matrix(
            self, check=check, max_vertices=max_vertices))

    @property
    def gradient_components32(self) -> list:
        """The three (F, V) component blocks of ``G`` in float32 (the k = 0 face pass)."""
        g = self.gradient_matrix
        return self._store.get(("emd", "gradient32"),
                               lambda: [g[c::3].astype(np.float32).tocsr() for c in range(3)])

    # -- curl basis ---------------------------------------------------------
    @property
    def consistently_oriented(self) -> bool:
        f = self.mesh.faces
        half = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        key = half[:, 0] * self.n_vertices + half[:, 1]
        return len(np.unique(key)) == len(key)

    def require_curl_basis(self) -> None:
        # Rotated gradients are divergence-free when every edge has at most two faces
        # with opposite orientations (pinched vertices are fine: each fan closes).
        if self.mesh.diagnostics.nonmanifold_edges or not self.consistently_oriented:
            raise UnsupportedDomainError(
                "the curl basis needs manifold edges and consistently oriented faces; use "
                "basis='flow' (the unrestricted flow space) for this mesh", field="basis")

    @property
    def stream_map(self) -> sp.csr_matrix:
        """``P`` (V × n_c): coefficients -> stream function values (see module docstring)."""
        return self._store.get(("emd", "stream"), self._build_stream_map)

    def _build_stream_map(self) -> sp.csr_matrix:
        self.require_curl_basis()
        nv = self.n_vertices
        loops = self.mesh.boundary_loops
        free = np.ones(nv, dtype=bool)
        for loop in loops:
            free[loop] = False
        loop_comp = np.array([self.labels[loop[0]] for loop in loops], dtype=np.int64)
        has_boundary = np.zeros(self.n_components, dtype=bool)
        has_boundary[loop_comp] = True
        closed_pins = self.pins[~has_boundary]
        free[closed_pins] = False
        cols = [np.flatnonzero(free)]
        rows = [cols[0]]
        ids = [np.arange(len(cols[0]))]
        next_col = len(cols[0])
        seen = set()
        for loop, comp in zip(loops, loop_comp, strict=True):
            if comp not in seen:  # the first loop of each component stays at s = 0
                seen.add(comp)
                continue
            rows.append(np.asarray(loop))
            ids.append(np.full(len(loop), next_col))
            next_col += 1
        r = np.concatenate(rows)
        c = np.concatenate(ids)
        return sp.csr_matrix((np.ones(len(r)), (r, c)), shape=(nv, next_col))

    @property
    def curl_factor(self):
        """Factor of ``K = Pᵀ L P``: the ADMM c-update system, once per mesh."""
        p = self.stream_map
        return self._store.get(("emd", "curl_factor"),
                               lambda: factorize_spd((p.T @ self.laplacian @ p).tocsc()))

    @property
    def interior_point_structure(self):
        """Tangent frames, divergence and normal-matrix pattern of the interior-point W1
        (:func:`solvers.emd.interior_point.flow_structure`), once per mesh."""
        return self._store.get(("emd", "interior_point"),
                               lambda: flow_structure(self.mesh, self._keep))

    @property
    def rotation_matrix(self) -> sp.csr_matrix:
        """``R`` as a block-diagonal (3F × 3F) matrix of cross products ``N ×``."""
        n_f, n = self.n_faces, self.normals
        base = 3 * np.arange(n_f)
        rows = np.concatenate([base, base, base + 1, base + 1, base + 2, base + 2])
        cols = np.concatenate([base + 1, base + 2, base, base + 2, base, base + 1])
        vals = np.concatenate([-n[:, 2], n[:, 1], n[:, 2], -n[:, 0], -n[:, 1], n[:, 0]])
        return sp.csr_matrix((vals, (rows, cols)), shape=(3 * n_f, 3 * n_f))

    @property
    def curl_matrix(self) -> tuple[sp.csr_matrix, sp.csr_matrix]:
        """``(Ψ, Ψᵀ diag(A))`` as sparse matrices (3F × n_c and n_c × 3F), built once."""
        def build():
            psi = (self.rotation_matrix @ self.gradient_matrix @ self.stream_map).tocsr()
            return psi, (psi.T @ sp.diags(np.repeat(self.face_areas, 3))).tocsr()

        return self._store.get(("emd", "curl_matrix"), build)

    def curl_field(self, c: np.ndarray) -> np.ndarray:
        """``Ψ c = N × ∇(P c)``: (n_c,) -> (F, 3).

        Parameters
        ----------
        c : (n_c,) array
            Stream-function coefficients.
        """
        return (self.curl_matrix[0] @ c).reshape(self.n_faces, 3)

    def curl_adjoint(self, field: np.ndarray) -> np.ndarray:
        """``Ψᵀ A field`` (n_c,).

        Parameters
        ----------
        field : (F, 3) array
            A face field.
        """
        return self.curl_matrix[1] @ field.ravel()

    # -- harmonic fields ----------------------------------------------------
    @property
    def harmonic_fields(self) -> np.ndarray:
        """(h, F, 3) divergence-free fields completing the curl basis (h = 2·genus).

        A-orthonormal and A-orthogonal to every curl field; empty for genus 0.
        """
        from solvers.emd.harmonic import harmonic_fields

        return self._store.get(("emd", "harmonic"), lambda: harmonic_fields(self))

    # -- spectral basis -----------------------------------------------------
    def stream_eigenbasis(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """First ``k`` eigenpairs of ``K φ = λ M φ`` (``M = Pᵀ diag(a) P``), φ M-orthonormal.

        Returns ``(eigenvalues (k,), vectors (n_c, k))``: the Laplacian eigenbasis of
        stream functions for the truncated (spectral) curl basis (§2.5).

        Parameters
        ----------
        k : int
            Number of eigenpairs, ``1 <= k < n_c - 1``.
        """
        n_c = self.stream_map.shape[1]
        if not 1 <= k < n_c - 1:
            from solvers.errors import InputError

            raise InputError(f"k must be in [1, {n_c - 2}], got {k}", field="k")
        key = ("emd", "stream_eigenbasis")
        eigen = self._store.peek(key)
        if eigen is None or eigen[0].shape[0] < k:
            p = self.stream_map
            mass = (p.T @ sp.diags(self.mesh.areas) @ p).tocsc()
            stiff = (p.T @ self.laplacian @ p).tocsc()
            factor = self.curl_factor
            op_inv = spla.LinearOperator(stiff.shape, matvec=factor.solve, dtype=np.float64)
            want = max(k, 2 * (0 if eigen is None else eigen[0].shape[0]))
            want = min(want, n_c - 2)
            vals, vecs = eigsh(stiff, k=want, M=mass, sigma=0.0, OPinv=op_inv,
                                    which="LM")
            order = np.argsort(vals)
            self._store.discard(key)  # replaced by the larger basis
            eigen = self._store.get(key, lambda: (vals[order], vecs[:, order]))
        vals, vecs = eigen
        return vals[:k], vecs[:, :k]
