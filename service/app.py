"""Application factory."""

from fastapi import FastAPI


def create_app() -> FastAPI:
    app = FastAPI(title="otgeo", version="0.1.0")

    @app.get("/healthz", operation_id="health")
    def healthz() -> dict:
        return {"status": "ok"}

    return app
