"""Whether a run had the machine to itself, and how every motion and reading was checked: what
the certificate states of it (issue 18). A protocol that grants one session at a time tells; one
without sessions (Modbus) cannot, and then the checks of every motion and reading are the
evidence that nobody else moved the machine."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from drivers.factory import resolve
from rtcal.procedure.models import Procedure
from rtcal.results.model import Control

if TYPE_CHECKING:
    from rtcal.methods.protocol import Method

MOVING = {"stage": "stage", "cmm": "cmm"}  # the instruments another client could move, and their kinds


def control_record(proc: Procedure, method: Method[Any, Any], simulated: bool, operator_address: str,
                   rejected_attempts: int) -> Control:
    """The run's control of its machine and its checks, from the procedure and how it was wired."""
    access: dict[str, str] = {}
    exclusive: bool | None = True
    if simulated:
        for name in proc.instruments.present():
            if name in MOVING:
                access[name] = "simulated in process: no other client can reach it"
    else:
        for name in proc.instruments.present():
            if name not in MOVING:
                continue
            address = getattr(proc.instruments, name).address
            _, model = resolve(MOVING[name], address)
            how = getattr(model.driver_class(), "exclusive_access", "")
            if how:
                access[name] = f"exclusive session: {how}"
            else:
                access[name] = (f"not known: the {model.name} {name}'s protocol ({', '.join(model.schemes)}) has no sessions, so "
                                "another client could reach it; "
                                "the checks of every motion and reading would have seen it move")
                exclusive = None
    if not method.operator_steps:
        access["operator"] = "none: the method's plan has no operator step"
    elif simulated:
        access["operator"] = "in process: the simulated bench re-seats its own polygon or tracer"
    elif operator_address:
        access["operator"] = "token: the simulated operator of `rtcal sim serve` obeys only requests carrying its printed token"
    else:
        access["operator"] = ("a person: asked before each operator step, who confirms it at this terminal or remotely "
                              "(the live page's Done or `rtcal control RUN_DIR confirm`, with the run's control token; without "
                              "--live, `rtcal control` from the run's own user)")
    return Control(instruments=access, exclusive=exclusive, checks=checks_text(proc, method), rejected_attempts=rejected_attempts)


def checks_text(proc: Procedure, method: Method[Any, Any]) -> list[str]:
    """What the engine checked at every motion and reading, with the procedure's tolerances: the
    stage's (every method's), then the method's own instruments' (its ``checks_text``)."""
    v = proc.verification
    stage = (f"{v.stage_tolerance_deg * 3600:g}″ (the procedure's stage tolerance)" if v.stage_tolerance_deg
             else "two steps of the drive (the default stage tolerance)")
    out = [f"stage: the drive's feedback position read after settling and again after the readings: within {stage} "
           "of the command, and unmoved while reading"]
    out += method.checks_text(proc)  # each method states its own instruments' checks
    out.append("a reading the checks contradict is kept, marked rejected and never used; a table or probe that moves "
               "while nothing is commanded stops the run without a certificate")
    return out
