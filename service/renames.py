"""Stored jobs from before the one vocabulary (issue 41, CHANGELOG "Unreleased"): their
request fields and decision keys under the old names, read under the new ones.

A job's ``params`` (its request JSON) and ``decision`` are stored as submitted.  A job
recorded before the renames (``route``/``algorithm``/``solver`` for an algorithm choice) must
still run when a worker claims it again, and its decision must still execute as decided:
:func:`current_params` and :func:`current_decision` rename the old keys (nothing else is
touched; a key already under its new name wins).
"""

from __future__ import annotations

# operation -> {old request field: new request field}
PARAMS: dict[str, dict[str, str]] = {
    "distances": {"route": "method", "algorithm": "w1_method"},
    "distance-matrices": {"route": "method", "algorithm": "w1_method"},
    "flows": {"algorithm": "method"},
    "anisotropic-distances": {"algorithm": "method"},
    "feature-distances": {"algorithm": "method"},
    "volumetric-distances": {"algorithm": "method"},
    "volumetric-paths": {"algorithm": "method"},
    "w1-barycenters": {"algorithm": "method"},
    "path-plans": {"algorithm": "method"},
    "histogram-propagations": {"route": "method", "algorithm": "periodic_method"},
    "metric-histogram-propagations": {"solver": "lp_method"},
    "brdf-interpolations": {"route": "method"},
    "soft-maps": {"landmark_route": "landmark_method"},
    "soft-map-analyses": {"dirichlet": "dirichlet_method"},
}
# the decisions of distances and distance matrices (the only operations with old decisions)
DECISION = {"route": "method", "routes": "methods", "algorithm": "w1_method"}
# a uniform matrix decision's explicit arguments of ``distance_matrix`` / the W1 options
SOLVER_ARGUMENTS = {"route": "method", "algorithm": "method"}


def _renamed(data: dict, names: dict[str, str]) -> dict:
    out = {}
    for key, value in data.items():
        new = names.get(key, key)
        if new != key and new in data:
            continue  # already stored under the new name
        out[new] = value
    return out


def current_params(operation: str, params: dict) -> dict:
    """``params`` of a stored ``operation`` job with its old field names renamed."""
    names = PARAMS.get(operation)
    if not names or not isinstance(params, dict):
        return params
    return _renamed(params, names)


def current_decision(decision: dict | None) -> dict | None:
    """A stored decision with its old keys renamed (``None`` stays ``None``)."""
    if not isinstance(decision, dict):
        return decision
    out = _renamed(decision, DECISION)
    if isinstance(out.get("solver_arguments"), dict):
        out["solver_arguments"] = _renamed(out["solver_arguments"], SOLVER_ARGUMENTS)
    return out
