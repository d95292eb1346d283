"""Pydantic request and response models of the REST API (v1)."""

from __future__ import annotations

import math
from datetime import UTC, datetime
from typing import Annotated, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field

from service.errors import ErrorBody, InvalidInput, PayloadTooLarge
from service.renames import current_decision
from solvers.domains import Domain, Graph, Grid, PointCloud, TriangleMesh, kind_supports
from solvers.errors import InputError
from solvers.validation import check_size


def timestamp(value: float | None) -> datetime | None:
    return None if value is None else datetime.fromtimestamp(value, tz=UTC)


# -- domains ----------------------------------------------------------------------
# Request bodies refuse Infinity/NaN (JSON extensions, or 1e400 read as inf) and type
# coercions (0 for false) at the door.
SPEC_CONFIG = ConfigDict(extra="forbid", allow_inf_nan=False, strict=True)


def _integral(value):
    """JSON Schema's integer: a number with a zero fractional part (``20.0`` too, as JSON
    Schema counts it), never a boolean (refused by the strict int that follows)."""
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return value


# The int of request models (strict otherwise: no bool, no numeric string)
Int = Annotated[int, BeforeValidator(_integral)]
# An edge of a request's graph: two different node indices (a list: strict validation of
# JSON arrays parsed to Python lists refuses tuples)
Index = Annotated[Int, Field(ge=0, le=2**63 - 1)]  # within int64
NodePair = Annotated[list[Index],
                     Field(min_length=2, max_length=2, json_schema_extra={"uniqueItems": True})]
# A stored domain's id (service.store): the content hash, lowercase hex
DOMAIN_ID_PATTERN = r"^[0-9a-f]{16,64}$"
DomainId = Annotated[str, Field(pattern=DOMAIN_ID_PATTERN)]
# An id in a URL path: one non-empty segment, neither "." nor ".." (a client's URL
# normalization removes those and so reaches another route); well-formed or not, an
# unknown id is a 404
PATH_SEGMENT = r"^([^/.][^/]*|\.[^/.][^/]*|\.\.[^/]+)$"
# A point in 3-D, a triangle's vertex indices
Point = Annotated[list[float], Field(min_length=3, max_length=3)]
Triangle = Annotated[list[Index],
                     Field(min_length=3, max_length=3, json_schema_extra={"uniqueItems": True})]


def check_point_limit(n: int, limit: int, field: str) -> None:
    """413 naming ``field`` when ``n`` points exceed ``limit`` (``max_vertices``)."""
    if n > limit:
        raise PayloadTooLarge(f"{n} points exceed the limit of {limit}", field=field)


def spec_array(values, field: str, dtype=np.float64) -> np.ndarray:
    """A JSON spec's rows as a 2-D array; 422 naming ``field`` when they are not."""
    try:
        arr = np.asarray(values, dtype=dtype)
    except (TypeError, ValueError, OverflowError) as exc:
        kind = "integers" if dtype is np.int64 else "numbers"
        raise InvalidInput(f"{field} must be a list of equal-length rows of {kind} (within "
                           "int64 for indices)", field=field) from exc
    if arr.ndim != 2:
        raise InvalidInput(f"{field} must be a list of equal-length rows", field=field)
    return arr


class _DomainSpec(BaseModel):
    """What every JSON domain spec answers before and while it is built (one subclass per
    kind, so the service never asks which kind it holds)."""

    size_field: ClassVar[str]  # the field that gives the domain's size (a 413 names it)

    def n_points(self) -> int:
        """Points the domain will carry (Python ints: a product cannot wrap): the value of
        its ``size_field``, or that field's length (rows of points or vertices)."""
        size = getattr(self, self.size_field)
        return int(size) if isinstance(size, int) else len(size)

    def build_bytes(self, per: dict[str, int]) -> int:
        """Working memory of the build, from the sizes alone (``per``: bytes per unit,
        ``service.domain_builder.BUILD_BYTES``)."""
        raise NotImplementedError  # pragma: no cover

    def build(self, max_vertices: int) -> Domain:
        """The domain, its size (:meth:`n_points`, named by ``size_field``) checked against
        ``max_vertices`` first (413)."""
        check_point_limit(self.n_points(), max_vertices, self.size_field)
        return self.construct()

    def construct(self) -> Domain:
        """The domain, unchecked."""
        raise NotImplementedError  # pragma: no cover


class GridSpec(_DomainSpec):
    model_config = ConfigDict(**SPEC_CONFIG, json_schema_extra={"examples": [
        {"kind": "grid", "shape": [32, 32]}]})
    kind: Literal["grid"]
    shape: list[Annotated[Int, Field(ge=2)]] = Field(
        min_length=1, max_length=3, description="nodes per axis (at least 2; their product at "
        "most OTGEO_MAX_VERTICES)")
    bounds: list[Annotated[list[float], Field(min_length=2, max_length=2)]] | None = Field(
        None, min_length=1, max_length=3, description="(lo, hi) per axis, one per axis of "
        "shape; default [0, 1]")
    periodic: bool | list[bool] = False
    size_field: ClassVar[str] = "shape"

    def n_points(self) -> int:
        """The product of the shape."""
        return math.prod(int(s) for s in self.shape)

    def build_bytes(self, per: dict[str, int]) -> int:
        """Per cell."""
        return per["grid_cell"] * self.n_points()

    def build(self, max_vertices: int) -> Grid:
        """The grid (its shape checked as Python integers)."""
        try:
            check_size(self.shape, max_vertices, "shape")
        except InputError as exc:
            raise PayloadTooLarge(exc.message, field="shape") from exc
        return self.construct()

    def construct(self) -> Grid:
        """The grid."""
        return Grid(self.shape, self.bounds, self.periodic)


class GraphSpec(_DomainSpec):
    model_config = ConfigDict(**SPEC_CONFIG, json_schema_extra={"examples": [
        {"kind": "graph", "n_nodes": 4, "edges": [[0, 1], [1, 2], [2, 3]],
         "weights": [1.0, 1.0, 2.0]}]})
    kind: Literal["graph"]
    n_nodes: Int = Field(ge=1)
    edges: list[NodePair] = Field(description="(m, 2) node index pairs (no self-loops)")
    weights: list[float] | None = None
    positions: list[list[float]] | None = None
    size_field: ClassVar[str] = "n_nodes"

    def build_bytes(self, per: dict[str, int]) -> int:
        """Per node and per edge."""
        return per["graph_node"] * int(self.n_nodes) + per["graph_edge"] * len(self.edges)

    def construct(self) -> Graph:
        """The graph."""
        return Graph(self.n_nodes, self.edges, self.weights, self.positions)


class PointCloudSpec(_DomainSpec):
    model_config = ConfigDict(**SPEC_CONFIG, json_schema_extra={"examples": [
        {"kind": "pointcloud", "n_neighbors": 5,
         "points": [[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)]}]})
    kind: Literal["pointcloud"]
    points: list[Point] = Field(min_length=4, description="(n, 3) coordinates, n >= 4")
    n_neighbors: Int = Field(30, ge=3, description="neighbors of each point in its local "
                             "triangulation")
    size_field: ClassVar[str] = "points"

    def build_bytes(self, per: dict[str, int]) -> int:
        """Per point and neighbor (more neighbors than other points is refused by the build
        itself, 422)."""
        neighbors = min(int(self.n_neighbors), max(len(self.points) - 1, 1))
        return per["pointcloud_neighbor"] * len(self.points) * neighbors

    def construct(self) -> PointCloud:
        """The point cloud."""
        return PointCloud(spec_array(self.points, "points"), n_neighbors=self.n_neighbors)


class MeshSpec(_DomainSpec):
    model_config = ConfigDict(**SPEC_CONFIG, json_schema_extra={"examples": [
        {"kind": "mesh", "vertices": [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]],
         "faces": [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]}]})
    kind: Literal["mesh"]
    vertices: list[Point] = Field(min_length=1, description="(n, 3) coordinates")
    faces: list[Triangle] = Field(min_length=1, description="(m, 3) vertex indices")
    laplacian: Literal["robust", "cotan"] = "robust"
    weld: bool = Field(False, description="merge vertices at equal positions (seams)")
    size_field: ClassVar[str] = "vertices"

    def build_bytes(self, per: dict[str, int]) -> int:
        """Per vertex and per face."""
        return per["mesh_vertex"] * len(self.vertices) + per["mesh_face"] * len(self.faces)

    def construct(self) -> TriangleMesh:
        """The mesh."""
        return TriangleMesh(spec_array(self.vertices, "vertices"),
                            spec_array(self.faces, "faces", np.int64),
                            laplacian=self.laplacian, weld=self.weld)


DomainSpec = Annotated[GridSpec | GraphSpec | PointCloudSpec | MeshSpec,
                       Field(discriminator="kind")]


class Boundary(BaseModel):
    loops: int
    closed: bool


class DomainOut(BaseModel):
    id: str = Field(description="content hash: the same upload gives the same id")
    kind: str
    n: int = Field(description="points carrying mass (vertices, nodes, cells)")
    sizes: dict[str, int]
    genus: int | None = None
    components: int
    boundary: Boundary | None = None
    diagnostics: dict = Field(default_factory=dict)
    warnings: list[str] = Field(default_factory=list)
    parameters: dict = Field(default_factory=dict)
    source: dict = Field(default_factory=dict, description="the upload that stored the domain")
    already_existed: bool = Field(False, description="this upload gave a domain stored "
                                  "before (same content id): it was not stored again, and "
                                  "`source` is the earlier upload")
    upload: dict | None = Field(None, description="this upload, when it differs from `source`")
    summary: dict = Field(default_factory=dict)
    created_at: datetime
    links: dict[str, str]

    @classmethod
    def from_meta(cls, meta: dict) -> DomainOut:
        s = meta["summary"]
        sizes = {k: int(s[k]) for k in ("vertices", "faces", "edges", "nodes", "points")
                 if isinstance(s.get(k), int)}
        if "shape" in s:
            sizes.update({f"axis{i}": int(v) for i, v in enumerate(s["shape"])})
        boundary = None
        if kind_supports(meta["kind"], "faces"):  # meshes: boundary loops
            boundary = Boundary(loops=int(s.get("boundary_loops", 0)),
                                closed=bool(s.get("closed", False)))
        diagnostics = dict(s.get("diagnostics") or {})
        warnings = list(diagnostics.pop("warnings", []))
        existed = bool(meta.get("already_existed"))
        if existed:
            src = meta.get("source") or {}
            name = src.get("filename") or "a JSON body"
            warnings.insert(0, f"this domain already existed: stored before from {name} "
                            f"({src.get('format', 'json')}); the stored domain is returned")
        return cls(id=meta["id"], kind=meta["kind"], n=int(s["n"]), sizes=sizes,
                   genus=s.get("genus"), components=int(s.get("components", 1)),
                   boundary=boundary, diagnostics=diagnostics, warnings=warnings,
                   parameters=meta.get("parameters") or {}, source=meta.get("source") or {},
                   already_existed=existed, upload=meta.get("upload") if existed else None,
                   summary=s, created_at=timestamp(meta.get("created_at", 0.0)),
                   links={"self": f"/v1/domains/{meta['id']}"})


class DomainList(BaseModel):
    domains: list[DomainOut]
    next_cursor: str | None = Field(None, description="pass as ?cursor= for the next page; "
                                    "null on the last page")


# -- jobs -------------------------------------------------------------------------
JobState = Literal["queued", "running", "succeeded", "failed", "cancelled"]


class JobProgress(BaseModel):
    iteration: int | None = None
    residual: float | None = None
    fraction: float | None = Field(None, description="estimated fraction done, 0..1 (from "
                                   "the residual's decrease towards tol, or iteration/max_iter)")
    eta_seconds: float | None = Field(None, description="estimated seconds left while running "
                                      "(elapsed × (1 − fraction) / fraction)")
    stage: str | None = Field(None, description="what a running job does before its solver "
                              "reports iterations (e.g. compiling its kernels on first use)")


class JobOut(BaseModel):
    id: str
    operation: str
    domain_id: str = Field(description="the job's domain; empty for a global operation "
                           "(color transfer, BRDF interpolation, several domains)")
    state: JobState = Field(description="`succeeded` only when the solver converged; a job "
                            "that stopped without converging is `failed` with error code "
                            "`not_converged` (its partial result stays readable)")
    progress: JobProgress
    queue: Literal["short", "long"] = Field(
        "short", description="the queue the job was sent to (chosen by its estimated cost)")
    queue_position: int | None = Field(None, description="while queued: 1 = next to run "
                                       "in its queue")
    attempts: int
    error: ErrorBody | None = None
    cancel_requested: bool
    time_limit: float
    decision: dict | None = Field(None, description="the operation's automatic choices (e.g. "
                                  "a distance's method and regularization), taken at "
                                  "submission from the request and the stored data alone "
                                  "and executed by every attempt of the job")
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    duration_seconds: float | None = None
    links: dict[str, str] = Field(description="self, result, events; result_glb for an "
                                  "operation with a glTF export (not e.g. a color transfer); "
                                  "domain for a job on a domain")

    @classmethod
    def from_row(cls, row, operations) -> JobOut:
        """The job ``row`` as the API shows it; ``operations`` (the registry) tells which
        links its operation serves."""
        base = f"/v1/jobs/{row.id}"
        return cls(
            id=row.id, operation=row.operation, domain_id=row.domain_id, state=row.state,
            progress=JobProgress(iteration=row.iteration, residual=row.residual,
                                 fraction=getattr(row, "fraction", None),
                                 eta_seconds=_eta(row), stage=getattr(row, "stage", None)),
            queue=getattr(row, "queue", None) or "short",
            queue_position=getattr(row, "queue_position", None),
            attempts=row.attempts, error=ErrorBody(**row.error) if row.error else None,
            cancel_requested=bool(row.cancel_requested), time_limit=row.time_limit,
            decision=current_decision(getattr(row, "decision", None)),
            created_at=timestamp(row.created_at), started_at=timestamp(row.started_at),
            finished_at=timestamp(row.finished_at), duration_seconds=row.duration,
            links=_job_links(base, row.domain_id,
                             operations.serves_glb(row.operation, row.domain_id)))


def _job_links(base: str, domain_id: str, glb: bool) -> dict[str, str]:
    """A job's links, each one served: ``result_glb`` only when the operation has a glTF
    (a color transfer has none: 409); ``domain`` only for a job on a domain (a global one,
    e.g. a color transfer, has none: ``/v1/domains/`` would be the listing)."""
    links = {"self": base, "result": f"{base}/result", "events": f"{base}/events"}
    if glb:
        links["result_glb"] = f"{base}/result.glb"
    if domain_id:
        links["domain"] = f"/v1/domains/{domain_id}"
    return links


RETRY_AFTER_MAX = 30  # seconds
RETRY_AFTER_HEADERS = {
    "Retry-After": {"description": "seconds to wait before polling the job (GET "
                    "/v1/jobs/{id}) again: its estimated time left while running, else 1 (short "
                    f"queue) or 5 (long queue); at most {RETRY_AFTER_MAX}",
                    "schema": {"type": "integer", "minimum": 1}},
    "Location": {"description": "the job: /v1/jobs/{id}", "schema": {"type": "string"}},
}


def retry_after(job: JobOut) -> int:
    """Seconds a client should wait before polling an unfinished job (``Retry-After``)."""
    import math

    eta = job.progress.eta_seconds
    if eta is not None:
        return max(1, min(RETRY_AFTER_MAX, math.ceil(eta)))
    return 5 if job.queue == "long" else 1


def _eta(row) -> float | None:
    """Seconds left of a running job from its fraction done (None until it reports one)."""
    import time

    fraction = getattr(row, "fraction", None)
    if row.state != "running" or not fraction or row.started_at is None:
        return None
    elapsed = max(time.time() - row.started_at, 0.0)
    return round(elapsed * (1.0 - fraction) / fraction, 3)


class JobList(BaseModel):
    jobs: list[JobOut]
    next_cursor: str | None = Field(None, description="pass as ?cursor= for the next page; "
                                    "null on the last page")


class ResultFileInfo(BaseModel):
    media_type: str
    bytes: int


class ArrayFile(BaseModel):
    """A result array as a NumPy ``.npy`` file: a short header (magic, dtype, shape), then the
    raw little-endian values in C order."""

    href: str = Field(description="where the file is served: GET /v1/jobs/{job_id}/arrays/"
                      "{name}.npy")
    media_type: Literal["application/x-npy"] = "application/x-npy"
    bytes: int = Field(description="size of the file")
    shape: list[int]
    dtype: str = Field(description="NumPy type of the values: float64, float32, int64, "
                       "bool, ...")


class JobResult(BaseModel):
    job_id: str
    operation: str
    domain_id: str
    decision: dict | None = Field(None, description="the job's decision (as in the job "
                                  "JSON), executed by the worker")
    values: dict = Field(description="scalars: value, iterations, residual, converged, "
                         "normalization of the inputs, ...")
    arrays: dict[str, list | None] = Field(
        default_factory=dict, description="the result arrays whose JSON fits the result's "
        "size budget (OTGEO_RESULT_JSON_BYTES, 1 MiB by default), smallest first, as nested "
        "lists (null for non-finite values); every array, inline or not, is in `array_files`")
    array_files: dict[str, ArrayFile] = Field(
        default_factory=dict, description="every result array as a .npy file (its link, "
        "shape and dtype); rows of 2-D arrays also one at a time: GET /v1/jobs/{job_id}/"
        "arrays/{name}/rows/{row}")
    export: dict = Field(default_factory=dict)
    files: dict[str, ResultFileInfo] = Field(
        default_factory=dict, description="files the job produced, each served at "
        "/v1/jobs/{job_id}/files/{name}")


class ArrayRow(BaseModel):
    name: str
    row: int
    values: list[float | None] = Field(description="the row (null for non-finite)")


class StorageHealth(BaseModel):
    writable: bool = Field(description="the data directory takes writes (probed)")
    low_space: bool = Field(False, description="free space below OTGEO_MIN_FREE_BYTES (the "
                            "free bytes are on /metrics, behind a key)")
    reason: str | None = Field(None, description="why it does not take writes")


class BrokerHealth(BaseModel):
    reachable: bool = Field(description="the queue's broker answers (Redis: PING; the "
                            "embedded SQLite queue: always)")
    reason: str | None = Field(None, description="why it is unreachable")


class Health(BaseModel):
    status: Literal["ok", "degraded"]
    queue: str
    version: str
    storage: StorageHealth | None = None
    broker: BrokerHealth | None = None
