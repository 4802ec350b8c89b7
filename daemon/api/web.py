"""The operator page and the API docs page, served from files: ``daemon/web/`` (plain HTML,
CSS and ES modules, no build step) at ``/`` and ``/static/``, and ``/docs`` with the Swagger
UI assets vendored under ``daemon/web/vendor/``. Nothing is loaded from another host."""

from __future__ import annotations

from pathlib import Path

from fastapi import FastAPI
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.staticfiles import StaticFiles

#: The front end's files (package data of ``daemon``).
WEB_DIR = Path(__file__).resolve().parents[1] / "web"
SWAGGER_DIR = "vendor/swagger-ui-dist-5.35.0"


def mount_web(app: FastAPI) -> None:
    """``/`` (the operator page), ``/static/*`` (its files) and ``/docs`` (Swagger UI from
    local files). The app must be created with ``docs_url=None, redoc_url=None``."""
    app.mount("/static", StaticFiles(directory=WEB_DIR), name="static")

    @app.get("/", include_in_schema=False)
    async def operator_page() -> FileResponse:
        # no-cache: a daemon upgrade must not leave a stale page in the browser.
        return FileResponse(WEB_DIR / "index.html", headers={"Cache-Control": "no-cache"})

    @app.get("/docs", include_in_schema=False)
    async def swagger_ui() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url=app.openapi_url or "/openapi.json",
            title=f"{app.title} REST API",
            swagger_js_url=f"/static/{SWAGGER_DIR}/swagger-ui-bundle.js",
            swagger_css_url=f"/static/{SWAGGER_DIR}/swagger-ui.css",
            swagger_favicon_url="/static/favicon.svg",
            # No badge that would ask the public validator service about the schema.
            swagger_ui_parameters={"validatorUrl": None},
        )
