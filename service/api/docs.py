"""/docs (Swagger UI) and /redoc served with their scripts from the installed package
``fastapi-offline`` (its bundled swagger-ui-dist and redoc standalone files), so the pages
work without network access to a CDN. Create the app with ``docs_url=None, redoc_url=None``
and call ``install(app)``.

``/guide/`` serves the built documentation site (``make docs``: Sphinx, MathJax included)
from ``OTGEO_GUIDE_DIR`` (default: the checkout's ``docs/_build/html``) when it is there;
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


def install_guide(app: FastAPI, guide_dir: Path | None) -> None:
    """Mount the built guide at /guide/ (offline, like /docs), or a 404 that says why."""
    directory = Path(guide_dir) if guide_dir is not None else DEFAULT_GUIDE_DIR
    if (directory / "index.html").is_file():
        app.mount(GUIDE_URL, StaticFiles(directory=directory, html=True), name="guide")
        return

    @app.get(GUIDE_URL + "/{path:path}", include_in_schema=False)
    async def guide_missing(path: str):
        """The user guide (the built docs site)."""
        from service.errors import NotFound

        raise NotFound("the guide is not built on this server (make docs builds it into "
                       "docs/_build/html, or set OTGEO_GUIDE_DIR)", field=None)


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
