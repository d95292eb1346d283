"""What an operation is, and the distribution inputs every operation shares.

A distribution is given as
- a full vector (one value per point),
- sparsely: ``{"indices": [...], "masses": [...]}``,
- a bump: ``{"vertex": i, "radius": r}`` — mass ``a_j max(0, 1 - d_j / r)`` around point
  ``i`` (``d``: Euclidean distance in the domain's stored coordinates, unit total area
  for meshes and point clouds; hops on graphs).

Values are masses by default (``"input": "density"`` for densities w.r.t. the area
weights); they must be finite and non-negative and are normalized to total mass 1
by the server, which reports the normalization.
"""

from __future__ import annotations

import math
import threading
import weakref
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.sparse.csgraph import shortest_path

from service.errors import InvalidInput, NotFound, UnsupportedOperation
from service.schemas import Int, NodePair  # noqa: F401 (NodePair: for the families)
from solvers.domains import CAPABILITIES, DOMAIN_KINDS, kind_supports, kinds_supporting
from solvers.emd.green import GREEN_MAX_VERTICES
from solvers.validation import (
    COMPONENT_MASS_TOL,
    check_component_masses,
    check_entropy_bound,
    check_gamma,
    check_gamma_resolved,
    check_indices,
    check_int,
    check_masses,
    mass_totals,
    normalized_columns,
)

Progress = Callable[[int, float], None]
ShouldCancel = Callable[[], bool]


# Request models: unknown fields, Infinity/NaN and type coercions (``0`` for ``false``,
# ``false`` for ``0``, ``"1"`` for ``1``) are refused, so what the spec says is what is accepted.
REQUEST_CONFIG = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


def given(*groups: str | tuple[str, ...], exactly: bool = True, nonempty: bool = False
          ) -> dict:
    """JSON Schema keywords (for ``json_schema_extra``) stating the rule the operation's
    validation enforces: exactly one (``exactly=False``: at least one) of ``groups`` is
    given. A group is a field name or a tuple of fields given together; given means present
    and not null (``nonempty``: a non-empty list). With ``exactly``, the fields of the
    other groups are then absent or null."""
    groups = [(g,) if isinstance(g, str) else tuple(g) for g in groups]
    present = {"minItems": 1} if nonempty else {"not": {"type": "null"}}

    def branch(group: tuple[str, ...]) -> dict:
        props = {name: present for name in group}
        if exactly:
            props.update({name: {"type": "null"} for other in groups if other != group
                          for name in other})
        return {"required": list(group), "properties": props}

    return {"oneOf" if exactly else "anyOf": [branch(g) for g in groups]}


def rules(*pairs: tuple[dict, dict]) -> dict:
    """JSON Schema keywords (for ``json_schema_extra``) stating conditional rules the
    operation's validation enforces: for each ``(when, then)``, a body whose fields match
    ``when`` (field -> schema; the fields present) must also match ``then`` (a schema)."""
    return {"allOf": [{"if": {"required": list(when), "properties": when}, "then": then}
                      for when, then in pairs]}


def needs(*fields: str) -> dict:
    """A ``then`` of :func:`rules`: ``fields`` given (present and not null)."""
    return {"required": list(fields),
            "properties": {name: {"not": {"type": "null"}} for name in fields}}


class SparseDistribution(BaseModel):
    model_config = REQUEST_CONFIG
    indices: list[Int] = Field(min_length=1, description="point indices")
    masses: list[float] = Field(min_length=1, description="value at each listed point")


class BumpDistribution(BaseModel):
    model_config = REQUEST_CONFIG
    vertex: Int = Field(ge=0, description="center point index")
    radius: float = Field(gt=0, description="support radius (unit-area coordinates; hops on "
                          "graphs)")


Distribution = list[float] | SparseDistribution | BumpDistribution


class OperationRequest(BaseModel):
    """Fields shared by every operation request (Infinity/NaN refused in every float)."""

    model_config = REQUEST_CONFIG
    input: Literal["masses", "density"] = Field(
        "masses", description="how distribution values are meant: masses per point, or "
        "densities with respect to the domain's area weights")
    time_limit: float | None = Field(None, gt=0, description="seconds (at most the server's "
                                     "job_time_limit)")


@dataclass
class DomainView:
    """The parts of a domain that input validation needs (from a stored DomainInfo or a
    built Domain): sizes, area weights, component labels, coordinates, graph edges."""

    kind: str
    n: int
    areas: np.ndarray
    component_labels: np.ndarray
    points: np.ndarray | None = None
    edges: np.ndarray | None = None
    n_faces: int | None = None
    memo: dict = field(default_factory=dict)  # lives on the source object: built once
    summary: dict = field(default_factory=dict)  # the stored domain's summary (API side)
    load_faces: Callable[[], np.ndarray] | None = None  # a mesh's (F, 3) faces, on demand
    sketch_builder: Callable[[], object] | None = None
    # the stored domain's artifact store (service.store.DomainArtifacts), None if unstored
    artifacts: object | None = None
    # what one request derives (per_request): on this view object, not its source
    request_memo: dict = field(default_factory=dict)

    def supports(self, capability: str) -> bool:
        """Whether the domain has ``capability`` (as ``Domain.supports``: what its kind
        offers)."""
        return kind_supports(self.kind, capability)

    def sketch(self):
        """The domain's :class:`~solvers.domains.sketch.DomainSketch` (what default decisions
        read: stored arrays, no operator), memoized on the view's source."""
        if "sketch" not in self.memo:
            self.memo["sketch"] = self.sketch_builder()
        return self.memo["sketch"]

    def per_request(self, name: str, req, compute: Callable[[], object]):
        """``compute()`` once per request object on this view (the last request's value
        kept per ``name``): a submission's ``validate``, memory estimate and ``decide`` run
        on the one view ``JobService`` makes for it, so what they all derive from the
        request (its resolved distributions) is derived once. Kept on the view, not on the
        domain's memo: it lives as long as the submission (or the worker's run)."""
        hit = self.request_memo.get(name)
        if hit is None or hit[0] is not req:
            hit = self.request_memo[name] = (req, compute())
        return hit[1]

    def point_tree(self):
        """k-d tree of ``points`` (bumps touch only the points within their radius)."""
        if "tree" not in self.memo:
            from scipy.spatial import cKDTree

            self.memo["tree"] = cKDTree(self.points)
        return self.memo["tree"]

    @property
    def faces_or_typical(self) -> int:
        """The mesh's face count, or ~2 per vertex (a closed triangle mesh's) when unknown:
        what the per-face cost and memory models take."""
        return int(self.n_faces or 2 * self.n)

    @property
    def n_components(self) -> int:
        return int(self.component_labels.max()) + 1 if len(self.component_labels) else 1


@dataclass(frozen=True)
class ResultFile:
    """A file produced by a job (an image, a GLB), served at ``/v1/jobs/{id}/files/{name}``."""

    media_type: str
    data: bytes


@dataclass
class OperationOutput:
    """A result: JSON values, named arrays (stored as .npz), files, and how to export them.

    ``export`` may hold ``fields`` (array names shown on the domain), ``flow`` (name of
    an ``(F, 3)`` per-face field), ``frames`` (times of ``(n, T)`` fields) and ``color``.
    ``files`` maps a file name (letters, digits, ``._-``) to a :class:`ResultFile`; a file
    named ``result.glb`` is what ``/result.glb`` returns instead of the generic export.
    """

    values: dict
    arrays: dict[str, np.ndarray] = field(default_factory=dict)
    export: dict = field(default_factory=dict)
    files: dict[str, ResultFile] = field(default_factory=dict)


class SubmitContext:
    """What a global operation's ``validate`` may look at: stored domains and blobs."""

    def __init__(self, store, settings, holds: Callable[[str, str], bool] | None = None):
        self.store = store
        self.settings = settings
        # holds(kind, id): whether the submitting tenant may use the stored object
        # (service.tenants); None: every object (workers, tests)
        self._holds = holds

    def _check_held(self, kind: str, object_id: str, field: str) -> None:
        if self._holds is not None and not self._holds(kind, object_id):
            raise NotFound(f"unknown {kind} {object_id!r}", field=field)

    def view(self, domain_id: str, field: str) -> DomainView:
        """The validation view of a stored domain; 404 naming ``field`` when unknown."""
        try:
            self.store.check_id(domain_id)
            self._check_held("domain", domain_id, field)
            return view_of_info(self.store.domain_info(domain_id))
        except NotFound as exc:
            raise NotFound(f"unknown domain {domain_id!r}", field=field) from exc

    def blob(self, blob_id: str, field: str) -> bytes:
        """The bytes of an uploaded blob; 404 naming ``field`` when unknown."""
        self.blob_meta(blob_id, field)
        return self.store.get_blob(blob_id, field=field)

    def blob_meta(self, blob_id: str, field: str) -> dict:
        meta = self.store.blob_meta(blob_id, field=field)
        self._check_held("blob", blob_id, field)
        return meta


class RunContext(SubmitContext):
    """What a global operation's ``run`` gets in the worker: built (cached) domains too."""

    def __init__(self, store, settings, load_domain: Callable[[str], object],
                 domain_id: str = ""):
        super().__init__(store, settings)
        self.domain_id = domain_id  # the job's domain (domain-scoped operations)
        self._load_domain = load_domain
        self.domains: dict[str, object] = {}  # domain id -> domain used by this job
        self._builds_before: dict[str, int] = {}
        self.fanout = None  # the job's blocks (service.jobs.fanout.FanOut) in a worker

    def domain(self, domain_id: str, field: str = "domain_id"):
        if domain_id not in self.domains:
            try:
                domain = self._load_domain(domain_id)
            except NotFound as exc:
                raise NotFound(f"unknown domain {domain_id!r}", field=field) from exc
            self.domains[domain_id] = domain
            self._builds_before[domain_id] = domain.operators.builds
        return self.domains[domain_id]

    def operator_builds(self) -> int:
        """Operators (factorizations, ...) built in the job's domains since first use."""
        return sum(d.operators.builds - self._builds_before[i] for i, d in self.domains.items())

    def run(self, op: Operation, request, progress, should_cancel,
            decision: dict | None = None) -> OperationOutput:
        """Run ``op``: a domain-scoped one on ``request``'s domain, a global one on this;
        an operation that decides at submission (``op.decide``) gets the job's stored
        ``decision`` (None for a job recorded before it had one: ``run`` then decides)."""
        extra = {} if op.decide is None else {"decision": decision}
        if op.fans_out:
            extra["fanout"] = self.fanout
        if op.scope == "domain":
            return op.run(self.domain(self.domain_id), request, progress, should_cancel,
                          **extra)
        return op.run(self, request, progress, should_cancel, **extra)


ALL_KINDS = DOMAIN_KINDS


@dataclass
class Operation:
    """One operation of the service.

    ``scope="domain"``: route ``POST /v1/domains/{domain_id}/<name>``; ``validate(view,
    req)`` runs at submission on the stored domain's :class:`DomainView` and returns the
    normalization reports; ``run(domain, req, progress, should_cancel)`` runs in a worker.
    One submission's ``validate``, ``estimate_bytes``, ``decide`` and ``estimate_cost`` get
    the same view: what several of them derive from the request (resolved distributions)
    is derived once through :meth:`DomainView.per_request`.

    ``scope="global"`` (operations over several domains, or over uploaded blobs): route
    ``POST /v1/<name>``; ``validate(ctx: SubmitContext, req)`` and ``run(ctx: RunContext,
    req, progress, should_cancel)``. ``domain_field`` names the request field holding the
    job's primary domain id (listed as the job's ``domain_id``), if any. ``route=False``:
    the family provides its own route (e.g. multipart uploads) and creates jobs through
    ``JobService.create``.

    ``result_model``: pydantic model of the result's ``values`` (typed SDK results).

    ``decide`` (optional): the operation's automatic choices (a route, a regularization, an
    algorithm...), taken once at submission from the request and the stored data alone
    (``decide(view, req)``, or ``decide(ctx: SubmitContext, req)`` for a global operation;
    cheap: no operator is built) and returned as a JSON-ready dict.  The job stores it
    (``decision``), the 202 and the job JSON show it, the result carries it, and every
    attempt of the job (a re-run after a worker died too) gets it as ``run(...,
    decision=...)`` and executes exactly it: the same request gives the same answer on any
    worker.
    """

    name: str  # URL segment, e.g. "pointwise-distances"
    operation_id: str  # OpenAPI operationId
    summary: str
    request_model: type[OperationRequest]
    run: Callable[..., OperationOutput]
    validate: Callable[..., list[dict]]
    # the capability (``Domain.supports``) a domain needs for this operation; None: every
    # domain (``kinds`` lists the kinds that have it)
    requires: str | None = None
    scope: Literal["domain", "global"] = "domain"
    domain_field: str | None = None
    route: bool = True
    result_model: type[BaseModel] | None = None
    # bytes of working memory a job needs, estimated at submission from (view, request)
    # (default: ``estimate_job_bytes``), or (SubmitContext, request) for a global operation;
    # checked against ``job_memory_bytes`` (a global operation checks in its ``validate``)
    estimate_bytes: Callable[..., int] | None = None
    # rows of arrays the operation derives from its stored ones on demand:
    # ``result_row(array, name, row)`` (``array(name)`` reads a stored result array) returns
    # row ``row`` of ``name``, or ``None`` when ``name`` is served as stored
    result_row: Callable[..., np.ndarray | None] | None = None
    decide: Callable[..., dict | None] | None = None
    # the job's cost from (points of its domain, request, context: the domain's view, or the
    # SubmitContext of a global operation), which picks its queue (default:
    # ``service.operations.cost.estimate_cost``, points x iterations x distributions)
    estimate_cost: Callable[..., float] | None = None
    # the request field a 413 names, from (view or SubmitContext, request): the field of the
    # larger part of the memory estimate, or None for the default (the first size-giving
    # field present)
    size_field: Callable[..., str | None] | None = None
    # progress counts items (pairs, problems) with their own fraction, not iterations: the
    # request's max_iter bounds each item, not the count
    progress_counts_items: bool = False
    # ``(view, request) -> bool``: this request's ``validate`` and ``decide`` are bounded
    # array work over the domain's points (no estimate, no solve, no operator built), so a
    # small domain's submission may run on the API's event loop (JobService.submits_on_loop)
    bounded_submission: Callable[..., bool] | None = None
    # ``run`` always writes the file ``result.glb``: /result.glb serves it even for a job
    # without a domain (a job with one gets the generic export of its domain otherwise)
    writes_glb: bool = False
    # ``run`` may split the job into blocks that any worker runs (service.jobs.fanout): it
    # gets ``fanout=`` (the worker's FanOut for the job; None outside a worker)
    fans_out: bool = False

    def serves_glb(self, domain_id: str | None) -> bool:
        """Whether ``GET /v1/jobs/{id}/result.glb`` has a glTF for this operation's job (on
        ``domain_id``): what service.job_service.JobService.result_glb returns."""
        return self.writes_glb or bool(domain_id)

    # ``() -> None``: a tiny run that compiles the numba kernels a job runs (or loads them
    # from numba's cache); service.warm runs it at worker start and before a first job
    warm: Callable[[], None] | None = None

    def __post_init__(self):
        if self.requires is not None and self.requires not in CAPABILITIES:
            raise ValueError(f"operation {self.name!r} requires {self.requires!r}, not a "
                             f"domain capability ({', '.join(CAPABILITIES)})")

    @property
    def kinds(self) -> tuple[str, ...]:
        """The domain kinds this operation runs on: every kind (in ``DOMAIN_KINDS`` order),
        or, when it ``requires`` a capability, those that have it (alphabetically)."""
        if self.requires is None:
            return ALL_KINDS
        return tuple(sorted(kinds_supporting(self.requires)))

    def check_kind(self, view: DomainView, field: str = "domain_id") -> None:
        """422 (``UnsupportedOperation``) when the domain lacks what the operation
        ``requires``."""
        if self.requires is not None and not view.supports(self.requires):
            raise UnsupportedOperation(
                f"{self.name} is not available on {view.kind} domains (only on "
                f"{', '.join(self.kinds)})", field=field)

    def primary_domain(self, request) -> str:
        """The job's ``domain_id`` column for a global operation ("" when none)."""
        if self.domain_field is None:
            return ""
        return str(getattr(request, self.domain_field, "") or "")


# -- distributions -------------------------------------------------------------
def _bump(view: DomainView, spec: BumpDistribution, field: str) -> np.ndarray:
    """Masses ``a_j max(0, 1 - d_j / r)`` around ``spec.vertex`` (hops on graphs)."""
    if spec.vertex >= view.n:
        raise InvalidInput(f"{field}.vertex {spec.vertex} out of range [0, {view.n - 1}]",
                           field=f"{field}.vertex")
    if view.supports("hop_metric"):
        import scipy.sparse as sp

        e = view.edges if view.edges is not None else np.zeros((0, 2), dtype=np.int64)
        adj = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(view.n, view.n))
        hops = shortest_path(adj, directed=False, unweighted=True, indices=spec.vertex)
        near = np.flatnonzero(hops <= spec.radius)
        d = hops[near]
    elif view.points is not None:
        center = view.points[spec.vertex]
        near = np.asarray(view.point_tree().query_ball_point(center, spec.radius), dtype=np.int64)
        diff = view.points[near] - center
        d = np.sqrt(np.einsum("ij,ij->i", diff, diff))
    else:
        raise UnsupportedOperation(f"this {view.kind} domain has no coordinates for a bump",
                                   field=field)
    values = np.zeros(view.n)
    values[near] = view.areas[near] * np.clip(1.0 - d / spec.radius, 0.0, None)
    return values


BUMP_MEMO_BYTES = 32 * 2**20  # resolved bumps kept per domain (view memo), at most 8


def _memo_bump(view: DomainView, spec: BumpDistribution, field: str
               ) -> tuple[np.ndarray, dict]:
    """Resolved bump masses, memoized on the view's source object (DomainInfo in the API,
    the cached Domain in a worker): repeated requests with the same bump neither search
    the k-d tree nor re-check a full vector. Callers get a copy of the array."""
    memo = view.memo
    lock = memo.setdefault("bumps_lock", threading.Lock())
    key = (int(spec.vertex), float(spec.radius))
    with lock:
        bumps = memo.setdefault("bumps", OrderedDict())
        hit = bumps.get(key)
        if hit is not None:
            bumps.move_to_end(key)
    if hit is None:
        hit = resolve_distribution(view, spec, field, memoize=False)
        with lock:
            bumps[key] = hit
            limit = max(1, min(8, BUMP_MEMO_BYTES // max(8 * view.n, 1)))
            while len(bumps) > limit:
                bumps.popitem(last=False)
    values, report = hit
    return values.copy(), {**report, "field": field}


def resolve_distribution(view: DomainView, spec, field: str, input_kind: str = "masses",
                         memoize: bool = True) -> tuple[np.ndarray, dict]:
    """Masses (n,) summing to 1 for one distribution spec, and the normalization report."""
    if isinstance(spec, BumpDistribution) and memoize:
        return _memo_bump(view, spec, field)
    if isinstance(spec, BumpDistribution):
        values = _bump(view, spec, field)
        input_kind = "masses"
    elif isinstance(spec, SparseDistribution):
        if len(spec.indices) != len(spec.masses):
            raise InvalidInput(f"{field}.indices and {field}.masses differ in length "
                               f"({len(spec.indices)} vs {len(spec.masses)})",
                               field=f"{field}.masses")
        idx = check_indices(spec.indices, view.n, field=f"{field}.indices")
        vals = check_masses(spec.masses, len(idx), field=f"{field}.masses")
        values = np.zeros(view.n)
        np.add.at(values, idx, vals)
    else:
        values = check_masses(spec, view.n, field=field)
        if values.ndim != 1:
            raise InvalidInput(f"{field} must be a flat list", field=field)
    if input_kind == "density":
        values = values * view.areas
    values = check_masses(values, view.n, field=field)
    peak, relative = mass_totals(values)
    with np.errstate(over="ignore", divide="ignore"):
        total, scale = float(peak * relative), float(1.0 / peak / relative)
    # beyond the float range (a total over 1.7e308, the scale of a subnormal total): null
    report = {"field": field, "given_total": total if math.isfinite(total) else None,
              "scale": scale if math.isfinite(scale) else None,
              "normalized": bool(abs(total - 1.0) > 1e-12)}
    return normalized_columns(values), report


def resolve_all(view: DomainView, specs: dict[str, object], input_kind: str
                ) -> tuple[dict[str, np.ndarray], list[dict]]:
    masses, reports = {}, []
    for name, spec in specs.items():
        masses[name], report = resolve_distribution(view, spec, name, input_kind)
        reports.append(report)
    return masses, reports


def resolve_weighted(view: DomainView, distributions: list, weights: list[float] | None,
                     input_kind: str) -> tuple[np.ndarray, np.ndarray, list[dict]]:
    """A barycenter's inputs: ``distributions`` (fields ``distributions[i]``) as the columns
    of an ``(n, k)`` array, with the same mass on every connected component, and their
    ``weights`` (the library's ``check_weights``: one per distribution, non-negative, a
    positive sum; uniform when None), normalized; plus the normalization reports."""
    from solvers.validation import check_weights

    specs = {f"distributions[{i}]": d for i, d in enumerate(distributions)}
    masses, reports = resolve_all(view, specs, input_kind)
    check_same_components(view, masses)
    w = check_weights(weights, len(distributions), "weights")
    return np.stack(list(masses.values()), axis=1), w, reports


def check_same_components(view: DomainView, masses: dict[str, np.ndarray],
                          tol: float | None = None) -> None:
    """On a domain with several components, transport cannot move mass between them:
    every distribution must put the same mass on each component. The library's check
    (``solvers.validation.check_component_masses``, L1 over components, at most
    ``COMPONENT_MASS_TOL`` or the request's smaller ``tol``), named after the first
    distribution that differs."""
    if view.n_components <= 1 or len(masses) < 2:
        return
    tol = COMPONENT_MASS_TOL if tol is None else min(float(tol), COMPONENT_MASS_TOL)
    names = list(masses)
    ref = masses[names[0]]
    for name in names[1:]:
        check_component_masses(view.component_labels, np.stack([ref, masses[name]], axis=1),
                               name, tol)


# Per built domain (a worker's cached object): values derived by validation, e.g. resolved
# bumps; dropped with the domain when the cache evicts it.
_DOMAIN_MEMOS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def view_of_domain(domain) -> DomainView:
    from service.store import domain_points
    from solvers.domains.sketch import DomainSketch

    memo = _DOMAIN_MEMOS.setdefault(domain, {})
    return DomainView(kind=domain.kind, n=int(domain.n), areas=np.asarray(domain.areas),
                      component_labels=np.asarray(domain.component_labels),
                      points=domain_points(domain), edges=domain.edges,
                      n_faces=domain.n_faces, memo=memo,
                      sketch_builder=lambda: DomainSketch.of(domain),
                      load_faces=(lambda: domain.faces) if domain.supports("faces") else None,
                      artifacts=domain.artifacts)


def view_of_info(info) -> DomainView:
    from solvers.domains.sketch import DomainSketch

    edges = info.arrays.get("edges") if info.supports("hop_metric") else None
    summary = info.meta["summary"]
    junctions = (summary.get("diagnostics") or {}).get("nonmanifold_vertices", 0)

    def sketch():  # the same sketch DomainSketch.of gives for the built domain
        return DomainSketch.from_stored(info.kind, info.arrays, info.points,
                                        info.component_labels, junctions)

    return DomainView(kind=info.kind, n=info.n, areas=info.areas,
                      component_labels=info.component_labels, points=info.points,
                      edges=edges, n_faces=summary.get("faces"), memo=info.memo,
                      sketch_builder=sketch, summary=summary,
                      load_faces=(lambda: info.arrays["faces"]) if info.supports("faces")
                      else None, artifacts=info.artifacts)


# -- sizes and scalar options, checked at submission and again in the worker -------------
def view_extent(view: DomainView) -> float:
    """The domain's size in its own units, as ``Domain.extent`` computes it (bounding-box
    diagonal of the stored points; hops on graphs), memoized on the view's source."""
    if view.supports("hop_metric"):  # graphs: the largest hop distance
        return float(max(view.n - 1, 1))
    if "extent" not in view.memo:
        from solvers.domains.base import points_extent

        view.memo["extent"] = points_extent(view.points)
    return view.memo["extent"]


def check_options(view: DomainView, req) -> None:
    """The request's scalar options against the domain, with the library's validators:
    ``gamma`` (at least what the domain resolves, ``GAMMA_RESOLUTION`` x h^2, at most
    ``GAMMA_MAX_FACTOR`` x extent^2), ``entropy_bound``
    (reachable), spectral basis sizes ``k`` (below the number of points)."""
    gamma = getattr(req, "gamma", None)
    if gamma is not None:
        check_gamma(gamma, view_extent(view), "gamma")
        check_gamma_resolved(gamma, view.sketch().length_scale, "gamma")
    bound = getattr(req, "entropy_bound", None)
    if bound is not None:
        check_entropy_bound(bound, view.areas, "entropy_bound")
    k = getattr(req, "k", None)
    spectral = getattr(req, "basis", "spectral") == "spectral"
    if k is not None and k != 0 and spectral:
        check_int(k, "k", low=1, high=max(view.n - 3, 1))
    if (getattr(req, "basis", None) == "spectral" and k is None
            and getattr(req, "metric", "w1") == "w1"):
        raise InvalidInput("basis 'spectral' needs k, the number of eigenfunctions", field="k")


# Cost units (``Operation.estimate_cost``, which picks the queue) a warm worker runs per
# second on one core: what the convolutional solvers' default cost (points x iterations x
# distributions) runs at (bench/results/operation_memory.md); an operation whose work is
# another kind of step converts its count to these units, so that the long-queue threshold
# (``long_job_cost``, 5e7) means about one second of work for every operation.
COST_PER_SECOND = 5e7



def estimate_job_bytes(view: DomainView, req) -> int:
    """Working memory of a job, estimated from its sizes (Python ints: no overflow).

    ``columns`` (n,)-vectors per distribution the solver keeps (~12 arrays each in the
    log-domain Sinkhorn iterations), plus spectral bases ``k`` x (2 V + 3 F) and the
    dense Green's matrix of exact pointwise distances (4 V^2 bytes) or, for k > 0, the
    block state of their batched ADMM."""
    n = int(view.n)
    faces = int(view.n_faces or 2 * n)
    if getattr(req, "distributions", None) is not None:
        columns = len(req.distributions) + 1
    elif getattr(req, "times", None) is not None:
        columns = 2 + len(req.times)
    elif getattr(req, "n_nodes", None) is not None and getattr(req, "edges", None) is not None:
        columns = int(req.n_nodes) + 2 * len(req.edges)
    else:
        columns = 2
    total = 12 * 8 * n * columns
    k = getattr(req, "k", None) or 0
    if k and getattr(req, "basis", "spectral") == "spectral":
        total += 2 * 8 * int(k) * (2 * n + 3 * faces)
    if hasattr(req, "source") and not k and n <= GREEN_MAX_VERTICES:
        total += 4 * n * n
    if hasattr(req, "source") and k:  # d_W^k: the batched ADMM's block state
        from solvers.emd.pointwise import ADMM_WORK_BYTES

        total += ADMM_WORK_BYTES
    return total


def job_memory_estimate(op: Operation, target, req) -> int | None:
    """The job's working memory estimated at submission: ``op.estimate_bytes(view, req)``
    (default :func:`estimate_job_bytes`) for a domain operation, ``op.estimate_bytes(ctx,
    req)`` for a global one (None when it has none). bench/operation_memory.py checks these
    against measured peaks."""
    if op.scope == "domain":
        return (op.estimate_bytes or estimate_job_bytes)(target, req)
    return None if op.estimate_bytes is None else op.estimate_bytes(target, req)


# the fields a 413 names by default: the first one the request gives
SIZE_FIELDS = ("distributions", "times", "edges", "n_nodes", "k", "points", "slice",
               "face_weights", "cost", "circle", "images", "n_phi")


def check_job_memory(op: Operation, view: DomainView | SubmitContext, req, limit: int
                     ) -> int | None:
    """413 (field: the request's size-giving field) when the job's estimated memory is
    above ``limit`` (``Settings.job_memory_bytes``); returns the estimate. ``view``: the
    SubmitContext for a global operation."""
    from service.errors import PayloadTooLarge

    estimate = job_memory_estimate(op, view, req)
    if estimate is not None and estimate > limit:
        field = ((op.size_field and op.size_field(view, req))
                 or next((f for f in SIZE_FIELDS if getattr(req, f, None)), None))
        advice = ("use method 'convolutional' (no dense kernel) or a coarser domain"
                  if field == "method" else "use fewer points or columns")
        raise PayloadTooLarge(f"this job would need about {estimate / 2**30:.3g} GiB of "
                              f"working memory, more than the limit of {limit / 2**30:.3g} GiB "
                              f"(OTGEO_JOB_MEMORY_BYTES): {advice}", field=field)
    return estimate
