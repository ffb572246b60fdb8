"""The run configuration's reference: every field by part, with its default and what it is."""

from typing import Any

from fastapi import APIRouter
from pydantic import BaseModel

from app.deps import ReadAuth
from app.schemas import errors
from contract.config import config_reference

router = APIRouter(prefix="/api/config", tags=["config"], responses=errors(401))


class ConfigFieldOut(BaseModel):
    name: str
    default: Any
    description: str


@router.get("", response_model=dict[str, list[ConfigFieldOut]])
def config_fields(_auth: ReadAuth) -> dict[str, list[ConfigFieldOut]]:
    """Per part (task, method, sac, networks, classifier, queries, evaluation, execution): the fields a run's
    `config` may set, with their defaults; the same list the New run form and docs/configuration.md show."""
    return {
        part: [ConfigFieldOut(name=name, default=default, description=doc) for name, default, doc in entries]
        for part, entries in config_reference().items()
    }
