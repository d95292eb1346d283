"""Application factory: ``create_app(settings)``."""

from __future__ import annotations

import asyncio
from contextlib import asynccontextmanager

from fastapi import Depends, FastAPI
from fastapi.openapi.utils import get_openapi
from pydantic import TypeAdapter

from service import __version__
from service.api import docs, domains, guards, health, images, jobs, operations, spec, viewer
from service.api.deps import require_api_key
from service.api.errors import install_handlers
from service.api.routelist import operations_markdown
from service.errors import ErrorResponse
from service.jobs.wake import JobWaiters
from service.runtime import Runtime
from service.schemas import DomainSpec
from service.settings import Settings

DESCRIPTION = """Optimal transport over geometric domains (meshes, grids, graphs, point clouds),
after J. Solomon, *Transportation Techniques for Geometric Data Processing* (2015).

Upload a domain, then create jobs on it (or on several domains, or on uploaded images); every
job is observable, cancellable and keeps its result. Errors are
`{"error": {"code", "message", "field"}}`."""

# Routers under /v1 (API key checked when configured); add new resource routers here.
# The operation routes are built per app from its registry (service.operations).
V1_ROUTERS = [domains.router, viewer.router, jobs.router, images.router]


def create_app(settings: Settings | None = None, *, start_background: bool = True) -> FastAPI:
    settings = settings or Settings()
    runtime = Runtime(settings, role="api")

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        if start_background:
            runtime.start_background(publish=settings.queue == "immediate")
        if settings.queue != "immediate":  # workers' "job done" datagrams wake ?wait requests
            runtime.waiters = JobWaiters(settings.data_dir)
            runtime.waiters.attach(asyncio.get_running_loop())
        try:
            yield
        finally:
            if runtime.waiters is not None:
                runtime.waiters.detach()
                runtime.waiters = None
            runtime.close()

    app = FastAPI(title="otgeo", version=__version__, description=DESCRIPTION,
                  lifespan=lifespan, docs_url=None, redoc_url=None)  # docs: local assets
    app.state.runtime = runtime
    install_handlers(app)
    guards.install(app)  # API key before the body is read; storage failures -> 503
    docs.install(app)  # /docs and /redoc with their scripts served from the package
    docs.install_guide(app, settings.guide_dir)  # the built docs site at /guide/
    auth = [Depends(require_api_key)]
    for router in [*V1_ROUTERS, operations.build_router(runtime.operations),
                   jobs.build_result_router(runtime.operations)]:
        app.include_router(router, dependencies=auth)
    app.include_router(health.router)
    viewer.install(app)  # the browser viewer at / and /viewer, assets under /static

    def openapi():
        if app.openapi_schema is None:
            # every operation listed from the route table (service.api.routelist)
            description = (f"{app.description}\n\n## Operations\n\n"
                           f"{operations_markdown(app, include_pages=False)}")
            schema = get_openapi(title=app.title, version=app.version,
                                 description=description, routes=app.routes)
            components = schema.setdefault("components", {}).setdefault("schemas", {})
            domain_spec = TypeAdapter(DomainSpec).json_schema(
                ref_template="#/components/schemas/{model}")
            components.update(domain_spec.pop("$defs", {}))
            components["DomainSpec"] = domain_spec
            components["ErrorResponse"] = ErrorResponse.model_json_schema(
                ref_template="#/components/schemas/{model}")
            components["ErrorResponse"].pop("$defs", None)
            spec.as_served(schema, settings)
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi
    return app
