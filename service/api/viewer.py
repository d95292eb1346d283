"""The browser viewer: ``/`` and ``/viewer`` (the page), ``/static`` (its assets, shipped in the
package: no build step, no network), and the read-only geometry a page needs to draw a domain,
``GET /v1/domains/{id}/geometry`` (under the API key like every /v1 route).

The page's source is ``viewer/`` (``npm run build`` copies it and the pinned three.js into
``service/static/``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from fastapi import APIRouter, FastAPI
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, Field

from service.api.deps import DomainSvc
from service.errors import responses
from solvers.domains import domain_class

STATIC_DIR = Path(__file__).resolve().parents[1] / "static"

router = APIRouter(prefix="/v1/domains", tags=["domains"])
pages = APIRouter(include_in_schema=False)


class DomainGeometry(BaseModel):
    """What a viewer draws; flat row-major arrays (``positions``: x, y, z per point)."""

    id: str
    kind: str
    n: int = Field(description="points carrying mass")
    dim: int = Field(3, description="coordinates per position")
    positions: list[float] | None = Field(None, description="(n, dim) flattened: mesh vertices "
                                          "and point clouds at unit total area (the units of "
                                          "bump radii), graph positions as uploaded")
    faces: list[int] | None = Field(None, description="(m, 3) flattened vertex indices")
    edges: list[int] | None = Field(None, description="(m, 2) flattened graph edges")
    shape: list[int] | None = Field(None, description="grid nodes per axis (C order)")
    bounds: list[list[float]] | None = Field(None, description="grid (lo, hi) per axis")


def _flat(a: np.ndarray | None, dtype) -> list | None:
    if a is None:
        return None
    a = np.asarray(a, dtype=dtype).ravel()
    return np.round(a, 7).tolist() if a.dtype.kind == "f" else a.tolist()


@router.get("/{domain_id}/geometry", operation_id="getDomainGeometry",
            response_model=DomainGeometry, responses=responses(401, 404))
def get_domain_geometry(domain_id: str, svc: DomainSvc):
    """Positions, faces, edges or grid shape of a stored domain (for drawing it)."""
    info = svc.info(domain_id)
    arrays, summary = info.arrays, info.meta["summary"]
    out = DomainGeometry(id=domain_id, kind=info.kind, n=info.n)
    parts = domain_class(info.kind).stored_geometry(arrays, summary, info.points)
    points = parts.get("points")
    if points is not None:
        points = np.asarray(points)
        out.dim = int(points.shape[1]) if points.ndim == 2 else 1
        out.positions = _flat(points, np.float32)
    if parts.get("faces") is not None:
        out.faces = _flat(parts["faces"], np.int64)
    if parts.get("edges") is not None:
        out.edges = _flat(parts["edges"], np.int64)
    if parts.get("shape") is not None:
        out.shape = [int(s) for s in parts["shape"]]
        out.bounds = [[float(v) for v in row] for row in parts["bounds"]]
        out.dim = len(out.shape)
    return out


def _index() -> FileResponse:
    return FileResponse(STATIC_DIR / "index.html", media_type="text/html",
                        headers={"Cache-Control": "no-cache"})


@pages.get("/")
def viewer_root():
    """The browser viewer."""
    return _index()


@pages.get("/viewer")
def viewer_page():
    """The browser viewer (the same page)."""
    return _index()


def install(app: FastAPI) -> None:
    """The page routes and the static mount (no API key: the page asks for one)."""
    app.include_router(pages)
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
