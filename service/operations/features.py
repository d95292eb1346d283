"""Distance to features on a mesh (thesis §2.7, Fig. 2.14): ``POST
/v1/domains/{id}/feature-distances``.

Features are vertices and/or curves (waypoints joined by shortest edge paths,
:mod:`solvers.emd.feature_curves`); the distance of every vertex to them comes from the
potential of W1 between the uniform distribution and masses on the features
(:func:`solvers.emd.distance_to_features`).  Results: ``distances`` (drawn on the domain),
the potential, the feature vertices and a mask of them.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from service.errors import InvalidInput
from service.operations.anisotropy import estimate_cost  # one W1 solve
from service.operations.base import (
    REQUEST_CONFIG,
    DomainView,
    Int,
    Operation,
    OperationOutput,
    OperationRequest,
    given,
)
from solvers.validation import check_indices

MAX_FEATURE_VERTICES = 1_000_000


class FeatureCurve(BaseModel):
    """A curve through waypoints (vertices), joined by shortest paths along mesh edges."""

    model_config = REQUEST_CONFIG
    waypoints: list[Int] = Field(min_length=2, max_length=10_000, description="vertices, in "
                                 "order along the curve")
    closed: bool = Field(False, description="join the last waypoint back to the first")


class FeatureDistanceRequest(OperationRequest):
    model_config = ConfigDict(json_schema_extra={"examples": [
        {"vertices": [0], "curves": [{"waypoints": [10, 40, 70], "closed": False}]}],
        **given("vertices", "curves", exactly=False, nonempty=True)})
    vertices: list[Int] = Field(default_factory=list, max_length=MAX_FEATURE_VERTICES,
                                description="feature vertices")
    curves: list[FeatureCurve] = Field(default_factory=list, max_length=256,
                                       description="feature curves")
    method: Literal["auto", "ipm", "admm", "weiszfeld"] = Field(
        "auto", description="W1 solver (auto: interior point over all flows)")
    basis: Literal["auto", "flow", "full"] = Field(
        "auto", description="flow space (auto: all flows; full: the thesis' curl basis)")
    tol: float | None = Field(None, gt=0, lt=1, description="solver tolerance (default 1e-4)")
    max_iter: Int | None = Field(None, ge=1, le=100_000)


class FeatureDistanceValues(BaseModel):
    """Values of a feature-distance job."""

    n_features: Int = Field(description="feature vertices (listed and on the curves)")
    max_distance: float | None
    unreachable: Int = Field(description="vertices on components without a feature (null "
                             "distances)")
    w1: float = Field(description="W1 between the uniform distribution and the feature "
                      "masses (each feature vertex gets the area of its Voronoi cell)")
    iterations: Int
    residual: float
    converged: bool


def validate(view: DomainView, req: FeatureDistanceRequest) -> list[dict]:
    if not req.vertices and not req.curves:
        raise InvalidInput("give feature vertices or curves", field="vertices")
    if req.vertices:
        check_indices(req.vertices, view.n, field="vertices")
    labels = np.asarray(view.component_labels)
    for i, curve in enumerate(req.curves):
        field = f"curves[{i}].waypoints"
        points = check_indices(curve.waypoints, view.n, field=field)
        if len(np.unique(labels[points])) > 1:
            raise InvalidInput(f"{field}: the waypoints lie on different connected components",
                               field=field)
    if req.method == "ipm" and req.basis == "full":
        raise InvalidInput("method 'ipm' solves over all flows (basis 'auto' or 'flow')",
                           field="basis")
    return []


def run(mesh, req: FeatureDistanceRequest, progress, should_cancel) -> OperationOutput:
    from service.operations.base import view_of_domain
    from solvers.emd import distance_to_features
    from solvers.emd.feature_curves import feature_set

    validate(view_of_domain(mesh), req)
    feats = feature_set(mesh, req.vertices,
                        [(c.waypoints, c.closed) for c in req.curves])
    kwargs = {"tol": req.tol} if req.tol is not None else {}
    res = distance_to_features(mesh, feats, method=req.method, basis=req.basis,
                               max_iter=req.max_iter, progress=progress,
                               should_cancel=should_cancel, **kwargs)
    d = np.asarray(res.distances, dtype=np.float64)
    finite = d[np.isfinite(d)]
    mask = np.zeros(mesh.n)
    mask[feats] = 1.0
    values = FeatureDistanceValues(
        n_features=int(len(feats)), max_distance=float(finite.max()) if finite.size else None,
        unreachable=int((~np.isfinite(d)).sum()), w1=float(res.emd.value),
        iterations=int(res.iterations), residual=float(res.residual),
        converged=bool(res.converged)).model_dump()
    arrays = {"distances": d, "potential": np.asarray(res.potential, dtype=np.float64),
              "features": feats, "feature_mask": mask}
    return OperationOutput(values, arrays, {"fields": ["distances", "feature_mask"],
                                            "color": "distances"})


OPERATIONS = [
    Operation("feature-distances", "createFeatureDistanceJob",
              "Distance of every vertex to feature vertices and curves from the W1 potential "
              "(thesis §2.7, Fig. 2.14)",
              FeatureDistanceRequest, run, validate, "faces",
              result_model=FeatureDistanceValues, estimate_cost=estimate_cost),
]
