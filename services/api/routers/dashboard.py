"""The dashboard page: one self-contained HTML file (no CDN: it must work without internet)."""

from __future__ import annotations

from importlib import resources

from fastapi import APIRouter
from fastapi.responses import HTMLResponse

from ..deps import DashboardHtmlDep

router = APIRouter(tags=["dashboard"])


def load_dashboard() -> str:
    """Read once at app creation (package data, so it works from a wheel too)."""
    return (resources.files("coplane.api") / "static" / "dashboard.html").read_text(encoding="utf-8")


@router.get(
    "/",
    response_class=HTMLResponse,
    responses={
        200: {"description": "The live dashboard", "content": {"text/html": {"schema": {"type": "string"}}}}
    },
    summary="Live dashboard (ENU plot, plane status, per-vehicle error; fed by /stream)",
)
async def dashboard(html: DashboardHtmlDep) -> HTMLResponse:
    return HTMLResponse(html)
