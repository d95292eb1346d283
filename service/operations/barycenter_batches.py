"""Batched barycenters: many barycenter problems over the same inputs, one per weight vector
(e.g. a whole grid of ``alphas`` as in thesis Fig. 3.4), solved as one job (thin adapter over
:func:`solvers.convolutional.barycenters`: the kernel applications of all active problems
form one multi-column block per step).

Each weight vector ``weights[b]`` is checked at submission with the library's validator
(one value per distribution, non-negative, positive sum; the error names ``weights[b]``).
Progress counts finished problems; a cancelled job keeps no partial result (the block's
problems finish together, so there is no finished part worth keeping).
"""

from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import Field

from service.errors import InvalidInput
from service.operations.base import (
    Distribution,
    DomainView,
    Int,
    Operation,
    OperationOutput,
    check_options,
    resolve_weighted,
    view_of_domain,
)
from service.operations.cost import DEFAULT_ITERATIONS
from service.operations.examples import BUMP_A, BUMP_B, example
from service.operations.transport import (
    ShapeMethodOption,
    ShapeMethodValues,
    as_ran,
    check_shape_method,
    kernel_bytes,
    shape_kwargs,
)
from solvers.convolutional import barycenters
from solvers.convolutional.matrix import block_pairs
from solvers.errors import InputError
from solvers.validation import check_weights

MAX_DISTRIBUTIONS = 64  # as /barycenters
MAX_PROBLEMS = 4096  # weight vectors per job (the request JSON stays small)
# float64 (n, k) arrays one active problem keeps (scalings, log-inputs, kernel inputs and
# outputs, marginals; bench/operation_memory.py checks the estimate against measured peaks)
PROBLEM_ARRAYS = 12
# float64 (n, B) arrays of the result: the solver's masses, the result's masses and density,
# and the stored copy
RESULT_ARRAYS = 4


class BarycenterBatchRequest(ShapeMethodOption):
    model_config = example({"distributions": [BUMP_A, BUMP_B],
                            "weights": [[1.0, 0.0], [0.75, 0.25], [0.5, 0.5], [0.25, 0.75]]})
    distributions: list[Distribution] = Field(min_length=1, max_length=MAX_DISTRIBUTIONS,
                                              description="the inputs shared by every problem")
    weights: list[Annotated[list[Annotated[float, Field(ge=0)]],
                            Field(min_length=1, max_length=MAX_DISTRIBUTIONS)]] = \
        Field(min_length=1, max_length=MAX_PROBLEMS, description="one weight vector per problem "
        "(B x k: one non-negative value per distribution, positive sum; each normalized)")
    sharpen: bool = Field(False, description="entropic sharpening (thesis Alg. 3)")
    entropy_bound: float | None = None
    debiased: bool = False


class BarycenterBatchValues(ShapeMethodValues):
    """Values of a batched-barycenter job: ``iterations`` (sum over problems), ``residual``
    (largest) and ``converged`` (all) summarize the problems; per problem, the arrays
    ``masses``/``density`` (V x B), ``problem_iterations``, ``problem_residuals``,
    ``problem_converged`` and ``entropies``."""

    problems: Int = Field(description="number of barycenter problems (B)")
    weights: list[list[float]] = Field(description="the normalized weight vectors (B x k)")
    entropy_bound: float | None = Field(None, description="the sharpening bound H0, if any")


def _weights(req: BarycenterBatchRequest) -> np.ndarray:
    """``(B, k)`` normalized weights, each row checked by the library's validator."""
    k = len(req.distributions)
    rows = []
    for b, w in enumerate(req.weights):
        field = f"weights[{b}]"
        if len(w) != k:
            raise InvalidInput(f"every row of weights needs {k} values (one per distribution); "
                               f"{field} has {len(w)}", field=field)
        if not any(w):
            raise InvalidInput(f"{field} sums to 0: give at least one positive weight",
                               field=field)
        try:  # also refuses a row whose sum overflows
            rows.append(check_weights(w, k, field))
        except InputError as exc:
            raise InvalidInput(str(exc), field=field) from exc
    return np.stack(rows)


def _inputs(view: DomainView, req: BarycenterBatchRequest):
    check_options(view, req)
    check_shape_method(view, req)
    weights = _weights(req)
    mus, _, reports = resolve_weighted(view, req.distributions, None, req.input)
    return mus, weights, reports


def validate(view: DomainView, req: BarycenterBatchRequest) -> list[dict]:
    return _inputs(view, req)[2]


def _memory_parts(view: DomainView, req: BarycenterBatchRequest) -> dict[str, int]:
    """Bytes growing with the inputs (``distributions``: the inputs and the active problems'
    (n, k) state), with the problems (``weights``: the (n, B) results) and the kernel's
    (``method``: the geodesic kernel's dense matrices)."""
    n, k, B = int(view.n), len(req.distributions), len(req.weights)
    active = min(B, block_pairs(n * k))  # as barycenters() sizes its block
    return {"distributions": 8 * n * k * (2 + PROBLEM_ARRAYS * active),
            "weights": 8 * n * B * RESULT_ARRAYS, "method": kernel_bytes(view, req)}


def estimate_bytes(view: DomainView, req: BarycenterBatchRequest) -> int:
    return sum(_memory_parts(view, req).values())


def size_field(view: DomainView, req: BarycenterBatchRequest) -> str:
    """The field of the larger part of the memory estimate (named by a 413)."""
    parts = _memory_parts(view, req)
    return max(parts, key=parts.get)


def estimate_cost(points: int, req: BarycenterBatchRequest, context=None) -> float:
    """Points x iterations x inputs x problems (each problem applies the kernel to its k
    columns every step)."""
    iterations = req.max_iter or DEFAULT_ITERATIONS
    return (float(max(points, 1)) * float(iterations) * len(req.distributions)
            * len(req.weights))


def run(domain, req: BarycenterBatchRequest, progress, should_cancel) -> OperationOutput:
    mus, weights, reports = _inputs(view_of_domain(domain), req)
    problems = len(weights)

    def over_problems(done: int, worst: float) -> None:
        progress(done, worst, done / problems)

    kwargs, reg = shape_kwargs(domain, req, over_problems, should_cancel)
    res = barycenters(domain, mus, weights, sharpen=req.sharpen,
                      entropy_bound=req.entropy_bound, debiased=req.debiased,
                      method=req.method, **kwargs)
    masses = np.asarray(res.masses, dtype=np.float64)
    values = BarycenterBatchValues(
        **as_ran(kwargs, reg, res.method), normalization=reports,
        iterations=int(res.iterations), residual=float(res.residual),
        converged=bool(res.converged), problems=problems, weights=res.weights.tolist(),
        entropy_bound=res.entropy_bound, method=res.method)
    arrays = {"masses": masses, "density": masses / np.asarray(domain.areas)[:, None],
              "problem_iterations": np.asarray(res.problem_iterations, dtype=np.int64),
              "problem_residuals": np.asarray(res.problem_residuals, dtype=np.float64),
              "problem_converged": np.asarray(res.problem_converged, dtype=bool),
              "entropies": np.asarray(res.entropies, dtype=np.float64)}
    export = {"fields": ["masses", "density"], "color": "density",
              "frames": list(range(problems))}
    return OperationOutput(values.model_dump(mode="json"), arrays, export)


OPERATIONS = [
    Operation("barycenter-batches", "createBarycenterBatchJob",
              "Many Wasserstein barycenters of the same distributions, one per weight vector "
              "(e.g. a grid of alphas), solved as one block; progress over problems",
              BarycenterBatchRequest, run, validate, result_model=BarycenterBatchValues,
              estimate_bytes=estimate_bytes, estimate_cost=estimate_cost,
              size_field=size_field, progress_counts_items=True),
]
