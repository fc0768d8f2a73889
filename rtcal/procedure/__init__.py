"""Procedures: YAML files validated by pydantic, with located errors."""

from rtcal.procedure.loader import load_procedure, load_scenario, procedure_schema
from rtcal.procedure.models import LaserTracerMultistation, Procedure

__all__ = ["LaserTracerMultistation", "Procedure", "load_procedure", "load_scenario", "procedure_schema"]
