"""Accuracy: running errors against the recording's truth, per vehicle and method."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from coplane.ids import VEHICLE_ID_PATTERN

from .. import views
from ..deps import StateDep
from ..models import AccuracyReport
from . import problems

router = APIRouter(tags=["accuracy"])


@router.get(
    "/accuracy",
    response_model=AccuracyReport,
    responses=problems(422),
    summary="Running H/V RMSE, CEP95, max errors and availability (needs truth)",
)
async def get_accuracy(
    state: StateDep,
    method: Annotated[str | None, Query(max_length=64, description="Only this method")] = None,
    vehicle_id: Annotated[
        str | None, Query(pattern=VEHICLE_ID_PATTERN, description="Only this vehicle")
    ] = None,
) -> AccuracyReport:
    rep = views.accuracy_report(state)
    if method is not None or vehicle_id is not None:
        rep.entries = [
            e
            for e in rep.entries
            if (method is None or e.method == method) and (vehicle_id is None or e.vehicle_id == vehicle_id)
        ]
    return rep
