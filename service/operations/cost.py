"""The default cost estimate of a job (domain size × iterations × columns): what an
operation without its own ``Operation.estimate_cost`` is charged, and the queue it goes to
follows from it (:func:`service.jobs.queue.queue_for_cost`).
"""

from __future__ import annotations

from service.operations.base import BumpDistribution, SparseDistribution

DEFAULT_ITERATIONS = 1000  # assumed when a request names no iteration bound


def estimate_cost(n: int, request, context=None) -> float:
    """A job's estimated cost at submission: domain size × iterations × columns.

    ``iterations`` is the request's ``max_iter`` (or ``iterations``), ``columns`` the number
    of distributions it carries (each one is a column of the kernel's multi-RHS solves),
    at least 1. Only used to choose a queue, so coarse is fine."""
    iterations = None
    for name in ("max_iter", "iterations", "n_iter"):
        value = getattr(request, name, None)
        if isinstance(value, int) and not isinstance(value, bool):
            iterations = value
            break
    columns = 0
    for name in type(request).model_fields:
        value = getattr(request, name, None)
        if isinstance(value, list) and value and all(_is_distribution(v) for v in value):
            columns += len(value)
        elif _is_distribution(value) and name not in ("weights",):
            columns += 1
    return float(max(n, 1)) * float(iterations or DEFAULT_ITERATIONS) * float(max(columns, 1))


def _is_distribution(value) -> bool:
    if isinstance(value, (BumpDistribution, SparseDistribution)):
        return True
    return isinstance(value, list) and len(value) > 1 and \
        all(isinstance(x, (int, float)) for x in value[:8])
