"""The API docs at /docs: Swagger UI served by the app itself (the `swagger-ui-py` package's copy of its files),
so it works without internet; no inline script, so the page keeps a strict Content-Security-Policy."""

from pathlib import Path

import swagger_ui
from fastapi import APIRouter, Request
from fastapi.responses import FileResponse, HTMLResponse
from fastapi.templating import Jinja2Templates

from app.deps import ReadAuth

SWAGGER_UI_DIR = Path(swagger_ui.__file__).resolve().parent / "static"
SWAGGER_UI_PREFIX = "/static/swagger-ui"  # mounted by app.main (public, like /static: the library's own files)
FAVICON = Path(__file__).resolve().parent.parent.parent / "static" / "favicon.svg"

router = APIRouter(include_in_schema=False)
templates = Jinja2Templates(directory=Path(__file__).resolve().parent.parent.parent / "templates")


@router.get("/docs", response_class=HTMLResponse)
def swagger_docs(request: Request, _auth: ReadAuth) -> HTMLResponse:
    return templates.TemplateResponse(request, "docs.html", {"assets": SWAGGER_UI_PREFIX})


@router.get("/favicon.ico")
def favicon() -> FileResponse:
    return FileResponse(FAVICON, media_type="image/svg+xml", headers={"Cache-Control": "max-age=86400"})
