"""/docs (Swagger UI) and /redoc served with their scripts from the installed package
``fastapi-offline`` (its bundled swagger-ui-dist and redoc standalone files), so the pages
work without network access to a CDN. Create the app with ``docs_url=None, redoc_url=None``
and call ``install(app)``.

``/guide/`` serves the built documentation site (``make docs``: Sphinx, MathJax included)
from ``OTGEO_GUIDE_DIR`` (default: the checkout's ``docs/_build/html``) when it is there,
looked for on every request (a build made while the server runs is served at once);
otherwise ``/guide/`` answers 404 saying how to build it."""

from __future__ import annotations

from pathlib import Path

from fastapi import FastAPI
from fastapi.openapi.docs import (
    get_redoc_html,
    get_swagger_ui_html,
    get_swagger_ui_oauth2_redirect_html,
)
from fastapi.staticfiles import StaticFiles

ASSETS_URL = "/docs-assets"
ASSET_FILES = ("swagger-ui-bundle.js", "swagger-ui.css", "redoc.standalone.js", "favicon.png")


def assets_dir() -> Path:
    import fastapi_offline

    return Path(fastapi_offline.__file__).resolve().parent / "static"


GUIDE_URL = "/guide"
DEFAULT_GUIDE_DIR = Path(__file__).resolve().parents[2] / "docs" / "_build" / "html"


class GuideFiles(StaticFiles):
    """The built guide, looked for on every request: ``make docs`` run while the server is up
    is served at once, and a removed build answers 404 saying how to build it again."""

    def __init__(self, directory: Path):
        super().__init__(directory=directory, html=True, check_dir=False)
        self.index = Path(directory) / "index.html"

    async def check_config(self) -> None:
        """Starlette checks the directory once, at the first request; the guide may come
        later (get_response checks it each time)."""

    async def get_response(self, path: str, scope):
        if not self.index.is_file():
            from service.errors import NotFound

            raise NotFound("the guide is not built on this server (make docs builds it into "
                           "docs/_build/html, or set OTGEO_GUIDE_DIR)", field=None)
        return await super().get_response(path, scope)


def install_guide(app: FastAPI, guide_dir: Path | None) -> None:
    """Mount the guide at /guide/ (offline, like /docs): the built site, or a 404 that says
    how to build it, decided per request."""
    directory = Path(guide_dir) if guide_dir is not None else DEFAULT_GUIDE_DIR
    app.mount(GUIDE_URL, GuideFiles(directory), name="guide")


def install(app: FastAPI) -> None:
    app.mount(ASSETS_URL, StaticFiles(directory=assets_dir()), name="docs-assets")
    openapi_url = app.openapi_url or "/openapi.json"
    oauth2_redirect = "/docs/oauth2-redirect"
    # The pages close over strings only, never over the app: FastAPI keeps endpoint functions
    # in module-level caches, and an endpoint holding the app would keep it, its runtime and
    # the operator cache (cholespy factors among them) alive until interpreter exit.
    title = app.title

    @app.get("/docs", include_in_schema=False)
    async def swagger_ui():
        """Swagger UI of the OpenAPI document."""
        return get_swagger_ui_html(
            openapi_url=openapi_url, title=f"{title} - Swagger UI",
            oauth2_redirect_url=oauth2_redirect,
            swagger_js_url=f"{ASSETS_URL}/swagger-ui-bundle.js",
            swagger_css_url=f"{ASSETS_URL}/swagger-ui.css",
            swagger_favicon_url=f"{ASSETS_URL}/favicon.png")

    @app.get(oauth2_redirect, include_in_schema=False)
    async def swagger_ui_redirect():
        """Swagger UI's OAuth2 redirect page."""
        return get_swagger_ui_oauth2_redirect_html()

    @app.get("/redoc", include_in_schema=False)
    async def redoc():
        """ReDoc of the OpenAPI document."""
        return get_redoc_html(openapi_url=openapi_url, title=f"{title} - ReDoc",
                              redoc_js_url=f"{ASSETS_URL}/redoc.standalone.js",
                              redoc_favicon_url=f"{ASSETS_URL}/favicon.png",
                              with_google_fonts=False)
