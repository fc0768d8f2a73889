"""A store filled the way the Abbe sequencer fills it, for the live view's tests (no instrument)."""

from __future__ import annotations

import json
import math
import threading
from pathlib import Path

from rtcal.methods import load_procedure
from rtcal.store.runstore import REJECTED, SKIPPED, Reading, RunStore
from rtcal.methods.abbe.plan import planned_visits
from rtcal.methods.abbe.plan import reseat_instruction

PROCEDURE = Path(__file__).resolve().parents[1] / "procedures" / "iso230_2_polygon.yaml"


def create_store(run_dir: Path) -> tuple[RunStore, list]:
    """A new store with the ISO 230-2 procedure's metadata, as `rtcal run` writes it, and its visits."""
    text = PROCEDURE.read_text()
    proc = load_procedure(PROCEDURE, False, text)
    store = RunStore.create(run_dir, {"method": proc.method, "procedure_path": str(PROCEDURE), "procedure_yaml": text,
                                      "instruments": proc.instruments.model_dump_json(), "status": "not started",
                                      "generation": "0", "large": "", "seed": "1"})
    return store, planned_visits(proc)


def deviation_arcsec(angle_deg: float, run: int) -> float:
    return 3.0 * math.sin(math.radians(angle_deg)) + 0.2 * run


def visit_readings(store: RunStore, k: int, v, t_s: float) -> list[Reading]:
    """One visit's rows as the Abbe plan (rtcal/methods/abbe/plan.py) stores them (one sample, an environment sensor)."""
    state = dict(station=v.step, seating=v.seating, run=v.run, direction=v.direction, commanded_angle_deg=v.angle_deg,
                 plan_index=k, segment=0, attempt=store.new_attempt())
    dev = deviation_arcsec(v.angle_deg, v.run)
    rows = [Reading(t_s, "stage", "feedback_deg", v.angle_deg, "deg", **state),
            Reading(t_s, "environment", "air_temperature_c", 20.1, "degC", **state),
            Reading(t_s + 0.1, "encoder", "angle_deg", v.angle_deg + (dev + 1.0) / 3600, "deg", sample=0, **state),
            Reading(t_s + 0.1, "autocollimator", "x_arcsec", dev, "arcsec", sample=0, **state),
            Reading(t_s + 0.1, "dial_indicator_1", "y_um", 1.5, "um", sample=0, **state),
            Reading(t_s + 0.1, "dial_indicator_2", "y_um", 2.5, "um", sample=0, **state),
            Reading(t_s + 0.2, "stage", "feedback_after_deg", v.angle_deg, "deg", **state)]
    return rows


class StoreWriter(threading.Thread):
    """Writes visits into a store like a running sequencer: one visit every ``interval_s`` (3 s of
    run clock each), a rejected attempt and a fault event at visit ``reject_at`` (taken again), a
    skipped one at ``skip_at`` (left for a resume: ``written`` counts the visits done); stops at
    ``stop_after`` visits (None: all) or when ``halt`` is set; ``hold`` pauses it (with ``engine``
    it says so in the meta as the engine does); at visit ``ask_at`` it asks the operator ``instruction``
    (the meta's ``operator_waiting``, as the engine's store writer keeps it) until ``confirmed`` is set."""

    def __init__(self, run_dir: Path, interval_s: float = 0.05, stop_after: int | None = None, reject_at: int = 3,
                 finish: bool = False, engine: bool = False, skip_at: int | None = 5):
        super().__init__(daemon=True)
        self.run_dir = run_dir
        self.interval_s = interval_s
        self.stop_after = stop_after
        self.reject_at = reject_at
        self.skip_at = skip_at
        self.finish = finish
        self.engine = engine  # also write what the engine writes: engine_state, planned_readings, current
        self.halt = threading.Event()
        self.hold = threading.Event()
        self.written = 0
        self.ask_at: int | None = None
        self.instruction = reseat_instruction(45.0, 15.0)  # what the waiting operator asks (the Abbe plan's words)
        self.asking = False
        self.confirmed = threading.Event()
        store, self.visits = create_store(run_dir)
        store.set_meta({"status": "running"})
        store.close()

    def run(self) -> None:
        self.store = RunStore.open(self.run_dir)  # SQLite connections stay in their thread
        t = 0.0
        try:
            for k, v in enumerate(self.visits):
                if self.stop_after is not None and k >= self.stop_after:
                    break
                if self.hold.is_set() and self.engine:
                    self.store.set_meta({"engine_state": "paused"})
                while self.hold.is_set() and not self.halt.is_set():
                    self.halt.wait(0.02)
                if self.engine:
                    self.store.set_meta({"engine_state": "running", "planned_readings": str(len(self.visits)),
                                         "current": json.dumps({"plan_index": k, "target_deg": v.angle_deg,
                                                                "run": v.run + 1, "direction": "+" if v.direction > 0 else "-"})})
                if k == self.ask_at:
                    self.store.set_meta({"operator_waiting": json.dumps({"instruction": self.instruction, "t_s": t, "step": 1})})
                    self.asking = True
                    while not self.confirmed.is_set() and not self.halt.is_set():
                        self.halt.wait(0.02)
                    self.asking = False
                    self.store.set_meta({"operator_waiting": ""})
                if self.halt.wait(self.interval_s):
                    break
                if k == self.reject_at:
                    rows = visit_readings(self.store, k, v, t)
                    self.store.add_event(t, "fault", f"stage: position at {v.angle_deg:g}° contradicts the command",
                                         "stage")
                    self.store.add_readings(rows + [Reading(t, "stage", REJECTED, 0.0, "", plan_index=k,
                                                            attempt=rows[0].attempt, run=v.run, direction=v.direction,
                                                            commanded_angle_deg=v.angle_deg)])
                    t += 3.0
                rows = visit_readings(self.store, k, v, t)
                if k == self.skip_at:  # the encoder's policy skipped its reading: the visit stays to do
                    rows[2] = Reading(t, "encoder", SKIPPED, 0.0, "", **{f: getattr(rows[2], f) for f in (
                        "sample", "station", "seating", "run", "direction", "commanded_angle_deg", "plan_index",
                        "segment", "attempt")})
                    self.store.add_readings(rows)
                else:
                    self.store.add_readings(rows)
                    self.written += 1
                t += 3.0
            if self.finish:
                self.store.set_meta({"status": "solved", **({"engine_state": "finished"} if self.engine else {})})
            elif self.engine:
                self.store.set_meta({"engine_state": "aborted" if self.halt.is_set() else "finished"})
        finally:
            self.store.close()
