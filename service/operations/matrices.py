"""Distance matrices: every pair of a collection, or a collection against templates, as one
job (thin adapter over :func:`solvers.convolutional.distance_matrix`).

Each W2 pair takes the single-pair default's decision (method and regularization, from the
request and the stored domain alone).  The job's :class:`MatrixDecision` is taken at
submission (``Operation.decide``: the library's per-pair ``decide_method`` on the stored
domain's sketch, summarized) and stored with the job: a uniform decision (every pair exact,
or one heat kernel) runs as explicit solver arguments; a mixed one runs the same
deterministic per-pair decision in the library and is checked against the record.  Pairs
sharing a heat kernel run as one multi-column block, exact pairs share one geodesic cost
matrix.  Progress counts pairs; a cancelled (or timed-out) job keeps the
entries finished so far as its result (``complete: false``, ``finished_rows``).

A W2 matrix of more than one block (``decision["blocks"]``: row ranges, :func:`row_blocks`)
fans out over the workers (service.jobs.fanout): each block is a job of its own computing
its rows (``distance_matrix(..., rows=...)``), the job merges them (:func:`merge_blocks`).
Memory is estimated for the whole matrix and per block (``matrix_bytes``, ``block_bytes``);
a fanned-out job is refused beyond the larger of its largest block and the merge.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, Field

from service.errors import InvalidInput, UnsupportedOperation
from service.operations.base import (
    COST_PER_SECOND,
    Distribution,
    DomainView,
    Int,
    Operation,
    OperationOutput,
    check_options,
    check_same_components,
    resolve_all,
    view_of_domain,
)
from service.operations.examples import BUMP_A, BUMP_B, example
from service.operations.transport import SinkhornOptions
from solvers.convolutional.matrix import (
    SHARED_COST_ENTRIES,
    W1_ONLY,
    DistanceMatrixResult,
    block_pairs,
    distance_matrix,
    exact_route_bytes,
    kernel_key,
    matrix_pairs,
    pair_state_bytes,
    prefers_stored_distances,
    zero_diagonal,
)
from solvers.domains import DOMAIN_CLASSES
from solvers.domains.mesh import GEODESICS_ARTIFACT
from solvers.emd.beckmann import resolve_method
from solvers.emd.dwk_matrix import W1MatrixDecision, decide_w1_method, working_bytes
from solvers.errors import CancelledError, InputError
from solvers.transport.decision import decide_method
from solvers.transport.exact import EXACT_KINDS

MAX_DISTRIBUTIONS = 2000  # per side of a matrix (the request JSON stays a few MB)
METHOD_CODES = {"": -1, "identical": 0, "exact": 1, "convolutional": 2, "w1": 3,
                "spectral": 4}
MAX_K = 200  # eigenfunctions of a spectral W1 matrix (the eigenbasis is k solves deep)
# Pairs decided one by one at submission: an exact-method decision costs ~20-30 us, an
# automatic regularization ~0.9-2.4 ms per pair (100 bumps on spot, measured), so at most a
# few seconds of the API's time; above it the decision records the requested arguments and
# the worker decides per pair, by the same function of the data, as the library does.
DECIDED_PAIRS = 1000
LISTED_KERNELS = 32  # heat kernels listed in a decision (more: counted)


class DistanceMatrixRequest(SinkhornOptions):
    model_config = example({"distributions": [BUMP_A, BUMP_B, {"vertex": 50, "radius": 0.2}]})
    distributions: list[Distribution] = Field(
        min_length=1, max_length=MAX_DISTRIBUTIONS, description="the collection (rows)")
    others: list[Distribution] | None = Field(
        None, min_length=1, max_length=MAX_DISTRIBUTIONS, description="optional second set "
        "(columns, e.g. templates); left out: the symmetric matrix of `distributions` (pairs "
        "i < j solved, mirrored; zero diagonal for debiased and exact values)")
    metric: Literal["w2", "w1"] = Field(
        "w2", description="w2: squared 2-Wasserstein distance per pair, as /distances computes "
        "it by default; w1: earth mover's distance (Beckmann problem), meshes only")
    method: Literal["auto", "convolutional", "exact", "interior_point", "spectral"] = Field(
        "auto", description="W2, per pair as for /distances: auto (exact for sparse "
        "supports when its modelled time fits, else convolutional), convolutional or exact; "
        "W1: interior_point (one certified W1 per pair, with `w1_method`), spectral (the "
        "thesis' d_W^k: every distribution embedded once, then a k-dimensional problem per "
        "pair; each value an upper bound of W1 with its certified gap, converging slowly in "
        "k) or auto (the interior point while its estimate fits 60 s, else spectral; decided "
        "from the sizes at submission and recorded in `decision`)")
    debiased: bool | None = Field(None, description="W2 convolutional: Sinkhorn divergence "
                                  "(default: true; false when gamma is given)")
    w1_method: Literal["auto", "ipm", "admm", "weiszfeld"] = Field(
        "auto", description="W1 only: the W1 method of each pair's single W1 (as for "
        "/distances) when the matrix is computed by method interior_point")
    k: Int | None = Field(None, ge=0, le=MAX_K, description="W1 spectral: Laplacian "
                          "eigenfunctions of the curl basis (default: the largest of 0, 5, "
                          "10, 20, 50, 100 estimated within 60 s); given with method auto: "
                          "spectral")


class KernelGroup(BaseModel):
    """Pairs solved as one block: they share this heat kernel."""

    gamma: float
    t: float
    substeps: int
    debiased: bool


class MatrixDecision(BaseModel):
    """What a distance-matrix job runs, decided at submission from the request and the
    stored domain alone and stored with the job (module docstring)."""

    metric: Literal["w2", "w1"]
    method: Literal["auto", "convolutional", "exact", "interior_point", "spectral"] = Field(
        description="as requested")
    reason: str
    pairs: int = Field(description="pairs to solve (the diagonal of a symmetric matrix "
                       "included unless it is zero by definition)")
    per_pair: bool = Field(description="every pair's method and kernel decided at submission "
                           f"(at most {DECIDED_PAIRS} pairs)")
    zero_diagonal: bool | None = Field(None, description="symmetric: the diagonal is zero by "
                                       "definition (debiased or exact), not solved")
    methods: dict[str, int] = Field(default_factory=dict, description="pairs per method")
    kernel_count: int = Field(0, description="distinct heat kernels (t, substeps) of the "
                              "convolutional pairs")
    kernels: list[KernelGroup] = Field(default_factory=list, description="those kernels "
                                       f"(the first {LISTED_KERNELS})")
    solver_arguments: dict | None = Field(None, description="a uniform decision: the "
                                          "explicit arguments every pair runs with")
    w1_method: Literal["ipm", "admm", "weiszfeld"] | None = Field(None, description="w1: "
                                                                  "the W1 method")
    w1_matrix_method: Literal["interior_point", "spectral"] | None = Field(
        None, description="w1: how the matrix is computed, decided from the sizes alone: "
        "interior_point (one W1 per pair with `w1_method`) or spectral (d_W^k)")
    k: Int | None = Field(None, description="w1 spectral: the eigenfunctions used")
    blocks: list[list[int]] | None = Field(
        None, description="w2: the row ranges [start, stop) the matrix is split into; each "
        "block is a job any worker may run, the job merges their results (one block: the "
        "matrix runs as one)")
    matrix_bytes: Int | None = Field(None, description="w2: working memory estimated for "
                                     "the whole matrix in one worker")
    block_bytes: Int | None = Field(None, description="w2: working memory estimated for "
                                    "the largest block (what a worker running a block "
                                    "needs; the job is refused above the limit at the "
                                    "larger of this and the merge)")


class DistanceMatrixValues(BaseModel):
    """Values of a distance-matrix job; the matrix itself is the array ``matrix`` (inline
    when it fits the result's JSON budget, always as ``.npy`` in ``array_files``)."""

    metric: Literal["w2", "w1"]
    shape: list[int] = Field(description="[rows, columns] of the matrix")
    symmetric: bool = Field(description="one collection against itself")
    complete: bool = Field(description="false when the job was cancelled or timed out: "
                           "unfinished entries are NaN (null inline)")
    finished_rows: list[int] = Field(description="rows whose every entry is computed")
    pairs_solved: int = Field(description="pairs computed (diagonal not counted)")
    methods: dict[str, int] = Field(description="pairs per method (exact, convolutional, w1, "
                                    "spectral)")
    method_codes: dict[str, int] = Field(description="legend of the `method_codes` array")
    kernels: list[KernelGroup] = Field(description="the heat kernels of convolutional pairs")
    iterations: int = Field(description="sum over pairs")
    residual: float | None = Field(description="largest pair residual (each solver's "
                                   "measured stopping quantity)")
    converged: bool = Field(description="every pair computed and converged")
    normalization: list[dict]
    decision: MatrixDecision | None = Field(None, description="the job's decision (taken at "
                                            "submission)")


def _inputs(view: DomainView, req: DistanceMatrixRequest):
    """``(rows, others, reports)``: the request's distributions as read-only ``(n, k)``
    columns (``others`` None for a symmetric matrix) and their normalization reports,
    resolved once per request on ``view`` (validation, memory estimate and decision share
    them: :meth:`~service.operations.base.DomainView.per_request`)."""
    return view.per_request("distance-matrix inputs", req, lambda: _resolve(view, req))


def _resolve(view: DomainView, req: DistanceMatrixRequest):
    check_options(view, req)
    if req.metric == "w1" and not view.supports("faces"):
        raise UnsupportedOperation("metric 'w1' is available on triangle meshes only",
                                   field="metric")
    if req.metric == "w2" and (req.method in W1_ONLY or req.k is not None):
        raise InvalidInput(f"method {req.method!r} and k choose the W1 algorithm (metric "
                           "'w1')", field="k" if req.k is not None else "method")
    if req.metric == "w1" and req.method in ("convolutional", "exact"):
        raise InvalidInput(f"method {req.method!r} is a W2 method; W1 takes auto, "
                           "interior_point or spectral", field="method")
    if req.metric == "w1" and req.method == "interior_point" and req.k is not None:
        raise InvalidInput("k selects the spectral d_W^k; the interior point takes none",
                           field="k")
    if req.metric == "w2" and req.method == "exact" and not view.supports("exact_transport"):
        raise UnsupportedOperation(f"method 'exact' is available on {', '.join(EXACT_KINDS)} "
                                   "domains; use method 'convolutional'", field="method")
    specs = {f"distributions[{i}]": d for i, d in enumerate(req.distributions)}
    specs.update({f"others[{j}]": d for j, d in enumerate(req.others or [])})
    masses, reports = resolve_all(view, specs, req.input)
    check_same_components(view, masses, req.tol)
    columns = list(masses.values())
    rows = np.stack(columns[:len(req.distributions)], axis=1)
    others = None if req.others is None else np.stack(columns[len(req.distributions):], axis=1)
    for shared in (rows, others):
        if shared is not None:
            shared.flags.writeable = False  # shared by every reader of the request's inputs
    return rows, others, reports


def validate(view: DomainView, req: DistanceMatrixRequest) -> list[dict]:
    return _inputs(view, req)[2]


def _sizes(req: DistanceMatrixRequest) -> tuple[int, int, int]:
    """``(rows, columns, pairs solved)``."""
    n = len(req.distributions)
    if req.others is None:
        return n, n, n * (n + 1) // 2
    return n, len(req.others), n * len(req.others)


def estimate_bytes(view: DomainView, req: DistanceMatrixRequest) -> int:
    """The larger of what a worker running one of the job's blocks needs
    (:func:`block_bytes`, the largest block) and what the job's own worker needs to merge
    them (:func:`merge_bytes`); a matrix run as one block (W1, or few pairs): the whole
    matrix's estimate (:func:`matrix_bytes`)."""
    blocks = _blocks(view, req)
    if len(blocks) <= 1:
        return matrix_bytes(view, req)
    return max(merge_bytes(view, req), max(block_bytes(view, req, b) for b in blocks))


def merge_bytes(view: DomainView, req: DistanceMatrixRequest) -> int:
    """The job's worker merging the blocks: the inputs and the matrix with its per-pair
    arrays (twice: merged, and the output), and one block's stored arrays."""
    n, m, _ = _sizes(req)
    return 8 * int(view.n) * (n + (m if req.others is not None else 0)) + 80 * n * m


def matrix_bytes(view: DomainView, req: DistanceMatrixRequest) -> int:
    """The whole matrix in one worker: :func:`block_bytes` of every row."""
    return block_bytes(view, req, None)


def block_bytes(view: DomainView, req: DistanceMatrixRequest,
                rows: list[int] | None) -> int:
    """Inputs (one float per point and distribution), the matrix and its per-pair arrays,
    and the larger of the block's per-pair solver state (unless every pair is exact) and,
    where pairs may take the exact method, their ground distances
    (:func:`ground_distance_bytes`), the rows' cost blocks and the LPs
    (:func:`exact_working_bytes`) of the rows ``[start, stop)`` (None: every row)."""
    n, m, _ = _sizes(req)
    points = int(view.n)
    total = 8 * points * (n + (m if req.others is not None else 0))
    total += 40 * n * m
    if req.metric == "w1":
        total += 8 * 120 * points  # Beckmann operators and interior-point state
        w1 = _w1_decision(view, req)
        if w1.method == "spectral":
            total += working_bytes(points, _faces(view), w1.k, n, m, req.others is None)
        return total
    blocks = exact = 0
    if req.method != "exact":  # method "exact": every pair is exact, no block runs
        blocks = block_pairs(points) * (pair_state_bytes(points) + 8 * 8 * points)
    if may_take_exact(view, req):
        exact = ground_distance_bytes(view) + exact_working_bytes(view, req, rows)
    # the exact pairs run first and release their working memory before the blocks run
    return total + max(blocks, exact)


# -- blocks: a W2 matrix split into row ranges, run by any worker (service.jobs.fanout) --
BLOCK_BATCHES = 4  # a block holds at least this many convolutional batches of pairs
MIN_BLOCK_PAIRS = 64
MAX_BLOCKS = 64  # blocks of one matrix at most (job rows)


def block_target(points: int) -> int:
    """Pairs per block: ``BLOCK_BATCHES`` of the convolutional route's batches
    (:func:`~solvers.convolutional.matrix.block_pairs`), at least ``MIN_BLOCK_PAIRS``, so a
    block keeps the batching that makes the matrix faster than its pairs one by one."""
    return max(MIN_BLOCK_PAIRS, BLOCK_BATCHES * block_pairs(points))


def row_blocks(row_pairs: list[int], target: int, most: int = MAX_BLOCKS) -> list[list[int]]:
    """Consecutive row ranges ``[start, stop)`` of about ``target`` pairs each
    (``row_pairs[i]``: the pairs of row ``i``), at most ``most`` ranges (the target grows to
    fit), none empty of rows; a function of the sizes alone."""
    total = sum(row_pairs)
    target = max(int(target), -(-total // most), 1)
    blocks, start, acc = [], 0, 0
    for i, count in enumerate(row_pairs):
        acc += count
        if acc >= target and i + 1 < len(row_pairs):
            blocks.append([start, i + 1])
            start, acc = i + 1, 0
    if start < len(row_pairs):
        if acc == 0 and blocks:  # trailing rows without pairs join the last block
            blocks[-1][1] = len(row_pairs)
        else:
            blocks.append([start, len(row_pairs)])
    return blocks


def requests_exact(req: DistanceMatrixRequest) -> bool:
    """Whether the request lets pairs take the exact method (method ``exact``, or ``auto``
    without gamma), on a domain that offers it."""
    return req.method == "exact" or (req.method == "auto" and req.gamma is None)


def may_take_exact(view: DomainView, req: DistanceMatrixRequest) -> bool:
    """Whether pairs of this W2 matrix may take the exact method on ``view``'s domain."""
    return view.supports("exact_transport") and requests_exact(req)


def _blocks(view: DomainView, req: DistanceMatrixRequest) -> list[list[int]]:
    """The W2 matrix's row blocks. One block for W1 (its spectral method embeds every
    distribution at once, its decision depends on the whole matrix's size) and where pairs
    may take the exact method: its ground distances between the supports (or the domain's
    stored all-pairs geodesics) are built once for the whole matrix, and a block would
    rebuild them for its rows (a spot 100 x 100 default matrix took minutes per block)."""
    n, m, _ = _sizes(req)
    if req.metric != "w2" or may_take_exact(view, req):
        return [[0, n]]
    if req.others is None:  # pairs i < j, and the diagonal (at most one pair per row)
        row_pairs = [n - i for i in range(n)]
    else:
        row_pairs = [m] * n
    return row_blocks(row_pairs, block_target(int(view.n)))


def _faces(view: DomainView) -> int:
    return int(view.n_faces or 2 * view.n)


def _w1_decision(view: DomainView, req: DistanceMatrixRequest) -> W1MatrixDecision:
    """:func:`~solvers.emd.dwk_matrix.decide_w1_method` for the request's sizes."""
    n, m, _ = _sizes(req)
    symmetric = req.others is None
    pairs = n * (n - 1) // 2 if symmetric else n * m
    try:
        return decide_w1_method(int(view.n), _faces(view), n + (0 if symmetric else m), pairs,
                                req.method, req.k)
    except InputError as exc:
        raise InvalidInput(str(exc), field=exc.field or "method") from exc


def exact_working_bytes(view: DomainView, req: DistanceMatrixRequest,
                        block: list[int] | None = None) -> int:
    """The exact method's row cost blocks and LPs
    (:func:`~solvers.convolutional.matrix.exact_route_bytes`) with every pair exact, from
    the distributions' support sizes: ``EXACT_THREADS`` LPs of the largest pair (a fixed
    cap, not this machine's CPUs, so every process estimates the same); ``block``: of
    the rows ``[start, stop)`` only (their pairs: all of them, bounding the block's)."""
    rows, _, _ = _inputs(view, req)
    col_sizes, covered_cols = view.per_request("distance-matrix column supports", req,
                                               lambda: _column_supports(view, req))
    in_rows = rows > 0 if block is None else rows[:, block[0]:block[1]] > 0
    row_sizes = np.count_nonzero(in_rows, axis=0).tolist()
    covered = (int(np.count_nonzero(in_rows.any(axis=1))), covered_cols)
    # the distances' columns: every point where the stored all-pairs ones may serve
    width = int(view.n) if prefers_stored_distances(view.n, *covered) else covered[1]
    return exact_route_bytes(row_sizes, col_sizes, width, _sizes(req)[2])


def _column_supports(view: DomainView, req: DistanceMatrixRequest) -> tuple[list[int], int]:
    """The columns' support sizes and the points they cover (once per request: every
    block's estimate shares them)."""
    rows, others, _ = _inputs(view, req)
    in_cols = (rows if others is None else others) > 0
    return (np.count_nonzero(in_cols, axis=0).tolist(),
            int(np.count_nonzero(in_cols.any(axis=1))))


def ground_distance_bytes(view: DomainView) -> int:
    """The exact pairs' ground distances at most (supports covering the domain), as the
    method builds them (:func:`solvers.convolutional.matrix._support_distances`, at most
    :data:`~solvers.convolutional.matrix.SHARED_COST_ENTRIES` entries): what the domain's
    kind needs for that many (``Domain.ground_distance_bytes``)."""
    points = int(view.n)
    dim = 3 if view.points is None else int(np.shape(view.points)[1])
    return DOMAIN_CLASSES[view.kind].ground_distance_bytes(
        points, min(SHARED_COST_ENTRIES, points * points), dim)


EXACT_PAIR_COST = 20.0  # cost units per points^2 of one exact pair (measured, with margin)


def estimate_cost(points: int, req: DistanceMatrixRequest, context=None) -> float:
    """Points x pairs x a typical solve's kernel applications; where exact pairs may run,
    ``EXACT_PAIR_COST`` x points^2 per pair (the LP on supports of a fraction of the
    domain: bench/results/operation_memory.md)."""
    pairs = float(max(_sizes(req)[2], 1))
    exact = req.metric == "w2" and requests_exact(req)
    if exact and (context is None or context.supports("exact_transport")):
        return (EXACT_PAIR_COST * float(max(points, 1)) ** 2 * pairs
                + geodesics_cost(context, req))
    return float(max(points, 1)) * pairs * 60.0


def geodesics_cost(view: DomainView | None, req: DistanceMatrixRequest) -> float:
    """Cost units of the stored domain's all-pairs ground distances where the exact pairs
    would use them (:func:`~solvers.convolutional.matrix.prefers_stored_distances`) and they
    are not stored data yet (``Domain.stored_ground_distance_seconds`` at
    ``COST_PER_SECOND``); 0 once stored: a function of the request and the stored domain,
    the same in every process."""
    if view is None or view.artifacts is None:
        return 0.0
    seconds = DOMAIN_CLASSES[view.kind].stored_ground_distance_seconds(int(view.n))
    if seconds == 0.0 or view.artifacts.has(GEODESICS_ARTIFACT):
        return 0.0
    rows, others, _ = _inputs(view, req)
    covered = [int(np.count_nonzero((m > 0).any(axis=1)))
               for m in (rows, rows if others is None else others)]
    return COST_PER_SECOND * seconds if prefers_stored_distances(view.n, *covered) else 0.0


def _output(res, reports, complete: bool, decision: dict) -> OperationOutput:
    codes = np.vectorize(METHOD_CODES.get, otypes=[np.int8])(res.methods)
    solved = (res.methods != "") & (res.methods != "identical")
    if res.symmetric:
        solved = np.triu(solved)
    kinds, counts = np.unique(res.methods[solved], return_counts=True)
    residual = float(res.residual)
    values = DistanceMatrixValues(
        metric=res.metric, shape=list(res.values.shape), symmetric=res.symmetric,
        complete=complete, finished_rows=res.finished_rows.tolist(),
        pairs_solved=int(solved.sum()), methods={str(k): int(c) for k, c in zip(kinds, counts,
                                                                           strict=True)},
        method_codes={k or "none": v for k, v in METHOD_CODES.items()},
        kernels=[KernelGroup(gamma=g, t=t, substeps=s, debiased=d) for g, t, s, d in
                 res.kernels],
        iterations=int(res.iterations), residual=residual if np.isfinite(residual) else None,
        converged=bool(res.converged and complete), normalization=reports,
        decision=decision)
    arrays = {"matrix": np.asarray(res.values, dtype=np.float64),
              "pair_iterations": np.asarray(res.pair_iterations, dtype=np.int64),
              "pair_residuals": np.asarray(res.pair_residuals, dtype=np.float64),
              "pair_converged": np.asarray(res.pair_converged, dtype=bool),
              "method_codes": codes}
    if res.lower is not None:  # W1: certified lower bounds (spectral: of d_W^k)
        arrays["lower_bounds"] = np.asarray(res.lower, dtype=np.float64)
    return OperationOutput(values.model_dump(), arrays)


def _kernels(decisions) -> tuple[dict[tuple, tuple], list]:
    """The convolutional pairs' heat kernels keyed as the library groups them (t, substeps):
    ``{key: (gamma, t, substeps, debiased) of its first pair}``, and the distinct full
    tuples."""
    groups: dict[tuple, tuple] = {}
    full = []
    for d in decisions:
        if d.method != "exact":
            key = kernel_key(d)
            groups.setdefault(key, (d.gamma, *key, bool(d.debiased)))
            full.append((d.gamma, *key, bool(d.debiased)))
    return groups, sorted(set(full))


def decide_matrix_job(view: DomainView, req: DistanceMatrixRequest) -> dict:
    """The job's :class:`MatrixDecision` at submission (``Operation.decide``): W1's solver,
    or every W2 pair's method and kernel by the library's ``decide_method`` on the stored
    domain's sketch (up to :data:`DECIDED_PAIRS` pairs), summarized; a uniform decision
    carries the explicit solver arguments that execute it."""
    rows, others, _ = _inputs(view, req)
    symmetric = others is None
    cols = rows if symmetric else others
    common = {"metric": req.metric, "method": req.method}
    if req.metric == "w1":
        return _decide_w1(view, req, rows, cols, symmetric, common)
    sketch = view.sketch().remembering_paths()
    args = {"method": req.method, "gamma": req.solver_gamma(),
            "substeps": req.substeps, "debiased": req.debiased}
    zero = None
    if symmetric:
        zero = zero_diagonal(sketch, rows, args["gamma"], args["debiased"], args["method"])
    pairs = matrix_pairs(rows.shape[1], cols.shape[1], symmetric, zero is False)
    common.update(_block_fields(view, req))
    if len(pairs) > DECIDED_PAIRS:
        return MatrixDecision(**common, pairs=len(pairs), per_pair=False, zero_diagonal=zero,
                              reason=f"{len(pairs)} pairs, more than {DECIDED_PAIRS}: each "
                              "pair's route and kernel decided in the worker by the same "
                              "function of the data").model_dump(mode="json")
    decisions = [decide_method(sketch, rows[:, i], cols[:, j], t=None, **args)
                 for i, j in pairs]
    methods: dict[str, int] = {}
    for d in decisions:
        methods[d.method] = methods.get(d.method, 0) + 1
    groups, full = _kernels(decisions)
    uniform = None
    if methods == {"exact": len(pairs)}:
        uniform = {"method": "exact"}
    elif len(full) == 1:
        uniform = decisions[0].solver_arguments()
        if symmetric and zero != zero_diagonal(sketch, rows, uniform["gamma"],
                                               uniform["debiased"], "convolutional"):
            uniform = None  # the explicit arguments would solve another diagonal
    reasons = sorted({d.reason for d in decisions}) or [
        "no pair to solve: one distribution, whose diagonal entry is zero"]
    return MatrixDecision(
        **common, pairs=len(pairs), per_pair=True, zero_diagonal=zero, methods=methods,
        kernel_count=len(groups),
        kernels=[KernelGroup(gamma=g, t=t, substeps=s, debiased=b)
                 for g, t, s, b in list(groups.values())[:LISTED_KERNELS]],
        solver_arguments=uniform,
        reason=reasons[0] if len(reasons) == 1 else f"{len(reasons)} reasons over the pairs, "
        f"e.g. {reasons[0]}").model_dump(mode="json")


def _block_fields(view: DomainView, req: DistanceMatrixRequest) -> dict:
    """The decision's ``blocks`` and its memory estimates (whole matrix, largest block)."""
    blocks = _blocks(view, req)
    return {"blocks": blocks, "matrix_bytes": matrix_bytes(view, req),
            "block_bytes": max(block_bytes(view, req, b) for b in blocks)}


def _decide_w1(view, req, rows, cols, symmetric: bool, common: dict) -> dict:
    """W1: how the matrix is computed, from the sizes (:func:`_w1_decision`), then the
    interior point's W1 method or the spectral ``k``, as explicit arguments."""
    w1 = _w1_decision(view, req)
    pairs = len(matrix_pairs(rows.shape[1], cols.shape[1], symmetric, False))
    if w1.method == "spectral":
        return MatrixDecision(**common, reason=f"W1 by the thesis' d_W^k: {w1.reason}",
                              pairs=pairs, per_pair=True, zero_diagonal=symmetric or None,
                              methods={"spectral": pairs} if pairs else {},
                              w1_matrix_method="spectral", k=w1.k,
                              solver_arguments={"method": "spectral", "k": w1.k}
                              ).model_dump(mode="json")
    try:
        w1_method, _ = resolve_method(req.w1_method, "auto")
    except InputError as exc:
        field = "w1_method" if exc.field in (None, "method") else exc.field
        raise InvalidInput(str(exc), field=field) from exc
    return MatrixDecision(**common, reason=f"W1 per pair (Beckmann problem): {w1.reason}",
                          pairs=pairs, per_pair=True, zero_diagonal=symmetric or None,
                          methods={"w1": pairs} if pairs else {}, w1_method=w1_method,
                          w1_matrix_method="interior_point",
                          solver_arguments={"method": w1_method}).model_dump(mode="json")


def _check_ran_as_decided(values: dict, decision: dict) -> None:
    """A complete matrix ran what its stored decision says (methods and kernels per pair)."""
    if not decision.get("per_pair") or not values["complete"]:
        return
    ran = (values["methods"], len(values["kernels"]))
    decided = (decision["methods"], decision["kernel_count"] if decision["metric"] == "w2"
               else 0)
    if ran != decided:
        raise RuntimeError(f"the matrix ran {ran}, not its decision {decided}")


def _solver_kwargs(req: DistanceMatrixRequest, decision: dict) -> dict:
    """The library's arguments executing the stored ``decision``."""
    optional = {k: getattr(req, k) for k in ("tol", "max_iter") if getattr(req, k) is not None}
    explicit = decision.get("solver_arguments")
    if req.metric == "w1" and decision.get("w1_matrix_method") == "spectral":
        return {"method": "spectral", "k": explicit["k"], "w1_options": optional}
    if req.metric == "w1":  # one W1 per pair (also jobs recorded before w1_matrix_method)
        return {"method": "interior_point", "w1_options": {**explicit, **optional}}
    if explicit is not None:
        return {**explicit, **optional}
    return {"gamma": req.solver_gamma(),
            "substeps": req.substeps, "debiased": req.debiased, "method": req.method,
            **optional}


def run(domain, req: DistanceMatrixRequest, progress, should_cancel,
        decision: dict | None = None, fanout=None) -> OperationOutput:
    """Execute the job's stored ``decision`` (taken at submission; decided here only for a
    job recorded without one): one block of it (``decision["block"]``: a block job), its
    blocks fanned out over the workers (``fanout``, more than one block) and merged here,
    or the whole matrix in this worker."""
    view = view_of_domain(domain)
    rows, others, reports = _inputs(view, req)
    if decision is None:
        decision = decide_matrix_job(view, req)
    if decision.get("block") is not None:
        return _run_block(domain, req, rows, others, progress, should_cancel, decision)
    if fanout is not None and len(decision.get("blocks") or []) > 1:
        return _run_fanned(req, reports, progress, should_cancel, decision, fanout)
    try:
        res = distance_matrix(domain, rows, others, metric=req.metric, progress=progress,
                              should_cancel=should_cancel, **_solver_kwargs(req, decision))
    except CancelledError as exc:
        partial = getattr(exc, "partial", None)
        if partial is not None:  # the runner stores it as the cancelled job's result
            exc.partial_output = _output(partial, reports, False, decision)
        raise
    except ValueError as exc:  # an input the library refused: name the request's field
        field = getattr(exc, "field", None)
        if field in ("distributions", "others", "method", "metric", "k"):
            raise InvalidInput(str(exc), field=field) from exc
        raise
    output = _output(res, reports, True, decision)
    _check_ran_as_decided(output.values, decision)
    return output


# -- fan-out: blocks of rows as jobs of their own, merged by the job (service.jobs.fanout) --
BLOCK_ARRAYS = ("matrix", "pair_iterations", "pair_residuals", "pair_converged",
                "method_codes")


def _block_output(res, block: dict) -> OperationOutput:
    """A block's stored result: its rows of the per-pair arrays and its kernels."""
    start, stop = block["rows"]
    codes = np.vectorize(METHOD_CODES.get, otypes=[np.int8])(res.methods[start:stop])
    solved = (res.methods != "") & (res.methods != "identical")
    values = {"block": block["index"], "rows": [start, stop],
              "pairs_solved": int((np.triu(solved) if res.symmetric else solved).sum()),
              "kernels": [list(k) for k in res.kernels]}
    arrays = {"matrix": res.values[start:stop], "pair_iterations": res.pair_iterations[
        start:stop], "pair_residuals": res.pair_residuals[start:stop],
        "pair_converged": res.pair_converged[start:stop], "method_codes": codes}
    return OperationOutput(values, arrays)


def _run_block(domain, req, rows, others, progress, should_cancel, decision: dict
               ) -> OperationOutput:
    """One block: the library on the block's rows only (each pair decided as in the whole
    matrix); cancelled, it keeps its finished pairs as its result."""
    block = decision["block"]
    try:
        res = distance_matrix(domain, rows, others, metric=req.metric, progress=progress,
                              should_cancel=should_cancel, rows=block["rows"],
                              **_solver_kwargs(req, decision))
    except CancelledError as exc:
        partial = getattr(exc, "partial", None)
        if partial is not None:
            exc.partial_output = _block_output(partial, block)
        raise
    return _block_output(res, block)


def _run_fanned(req, reports, progress, should_cancel, decision: dict, fanout
                ) -> OperationOutput:
    """Record the blocks, let the workers (this one included) run them, merge them."""
    children = [{**decision, "blocks": None, "block": {"index": k, "rows": list(b)}}
                for k, b in enumerate(decision["blocks"])]
    n, m, _ = _sizes(req)
    try:
        finished = fanout.run(children, progress, should_cancel, decision["pairs"])
    except CancelledError as exc:
        parts = (fanout.result(row) for row in getattr(exc, "blocks", []))
        exc.partial_output = _output(merge_blocks(n, m, req.others is None, parts), reports,
                                     False, decision)
        raise
    res = merge_blocks(n, m, req.others is None, (fanout.result(r) for r in finished))
    output = _output(res, reports, True, decision)
    _check_ran_as_decided(output.values, decision)
    return output


def merge_blocks(n: int, m: int, symmetric: bool, parts) -> DistanceMatrixResult:
    """The matrix from its blocks' stored results ``(values, arrays)`` (a block that stored
    none: ``({}, {})``): each block's computed entries at its rows (mirrored when
    ``symmetric``), the kernels in row order, the summaries as the library computes them;
    an entry two blocks computed raises (a block's result is merged once)."""
    out = {"matrix": np.full((n, m), np.nan), "pair_iterations": np.zeros((n, m), np.int64),
           "pair_residuals": np.full((n, m), np.nan),
           "pair_converged": np.zeros((n, m), bool),
           "method_codes": np.full((n, m), METHOD_CODES[""], np.int8)}
    kernels: dict[tuple, tuple] = {}
    for values, arrays in parts:
        if not arrays:
            continue
        start, stop = values["rows"]
        done = arrays["method_codes"] != METHOD_CODES[""]
        if (out["method_codes"][start:stop][done] != METHOD_CODES[""]).any():
            raise RuntimeError(f"block {values['block']} overlaps an earlier block")
        for name in BLOCK_ARRAYS:
            out[name][start:stop][done] = arrays[name][done]
            if symmetric:
                out[name].T[start:stop][done] = arrays[name][done]
        for g, t, sub, deb in values["kernels"]:
            kernels.setdefault((t, sub), (g, t, sub, deb))
    names = {code: name for name, code in METHOD_CODES.items()}
    methods = np.vectorize(names.get, otypes=[object])(out["method_codes"])
    computed = methods != ""
    return DistanceMatrixResult(
        values=out["matrix"], pair_iterations=out["pair_iterations"],
        pair_residuals=out["pair_residuals"], pair_converged=out["pair_converged"],
        methods=methods, computed=computed, metric="w2", symmetric=symmetric,
        kernels=list(kernels.values()), iterations=int(out["pair_iterations"].sum()),
        residual=float(np.nanmax(out["pair_residuals"])) if computed.any() else float("nan"),
        converged=bool(computed.all() and out["pair_converged"][computed].all()))


OPERATIONS = [
    Operation("distance-matrices", "createDistanceMatrixJob",
              "Distances between every pair of a collection, or between a collection and "
              "templates (W2^2 per pair as /distances by default, or W1): the matrix, with "
              "progress over pairs; a cancelled job keeps its finished rows",
              DistanceMatrixRequest, run, validate, result_model=DistanceMatrixValues,
              estimate_bytes=estimate_bytes, estimate_cost=estimate_cost,
              decide=decide_matrix_job, progress_counts_items=True, fans_out=True),
]
