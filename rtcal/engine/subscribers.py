"""What listens to the engine: the store writer (every reading and event, committed as published),
and the console's progress (a bar on a terminal, a line every 10 % or 60 s in a log).

The live view does not subscribe: it reads the run's store from its own thread or process
(:mod:`rtcal.live`), so a viewer can never hold up or crash the measurement. What it needs beyond
the readings — the engine's state, the planned count, where the run is — the store writer keeps in
the store's metadata.
"""

from __future__ import annotations

import json
import math
import sys
import time
from typing import Any, Callable, TextIO

from rtcal.store.runstore import RunStore

OPERATOR_WAITING = "operator_waiting"  # the store's meta key the live view reads
ETA_KEY = "eta_s"  # the store's meta key of the time left (the live view shows what the log says)


class Eta:
    """The time left: one estimate for the console's log and the live page (through the store).

    The plan's remaining machine time as the walk counts it (:attr:`PlanWalk.entry_s`: motions,
    settles, samples, and each operator step at its stated duration), the machine part scaled by
    the pace this start has kept against the walk once it has ``MIN_BASIS_S`` of it. Time paused and
    an operator's wait for a person are no machine time and not counted; a resume walks only
    the entries still to take. The pending entries' machine and operator time are running totals:
    a document costs O(1), whatever the plan's length."""

    MIN_BASIS_S = 30.0

    def __init__(self, entry_s: dict[int, tuple[float, float]], virtual_clock: bool):
        self.entry_s = entry_s
        self.virtual_clock = virtual_clock  # a virtual clock counts an operator step's stated time itself
        self.pending = set(entry_s)
        self._pending_machine_s = math.fsum(total - operator for total, operator in entry_s.values())
        self._pending_operator_s = math.fsum(operator for _, operator in entry_s.values())
        self.machine_s = 0.0  # measured machine time of the entries done in this start …
        self.walked_s = 0.0  # … and the walk's for them
        self._t_s: float | None = None
        self._excluded_s = 0.0
        self._paused_at: float | None = None
        self._asked_at: float | None = None

    def _resumed(self, t_s: float, since: float | None) -> None:
        if since is not None:
            self._excluded_s += max(0.0, t_s - since)

    def __call__(self, name: str, doc: dict[str, Any]) -> None:
        if name == "start":
            self._t_s = doc["t_s"]
        elif name == "state":
            if doc["state"] == "paused" and self._paused_at is None:
                self._paused_at = doc["t_s"]
            elif doc["state"] != "paused":
                self._resumed(doc["t_s"], self._paused_at)
                self._paused_at = None
        elif name == "operator":
            if doc["instruction"]:
                self._asked_at = doc["t_s"]
            else:
                self._resumed(doc["t_s"], self._asked_at)
                self._asked_at = None
        elif name == "done":
            k = doc["index"]
            if k in self.pending and self._t_s is not None:
                self.pending.discard(k)
                total, operator = self.entry_s[k]
                self._pending_machine_s -= total - operator
                self._pending_operator_s -= operator
                spent = doc["t_s"] - self._t_s - self._excluded_s - (operator if self.virtual_clock else 0.0)
                self.machine_s += max(0.0, spent)
                self.walked_s += total - operator
            self._t_s, self._excluded_s = doc["t_s"], 0.0

    def eta_s(self) -> float:
        pace = 1.0
        if self.walked_s >= self.MIN_BASIS_S and self.machine_s > 0:
            pace = min(max(self.machine_s / self.walked_s, 0.2), 5.0)
        if not self.pending:  # what the running totals hold beyond this is rounding
            return 0.0
        return pace * max(self._pending_machine_s, 0.0) + max(self._pending_operator_s, 0.0)


class StoreWriter:
    """Commits each ``readings`` and ``event`` document to the run's store before the engine goes on,
    and keeps ``engine_state``, ``planned_readings``, ``current``, the time left and ``operator_waiting`` (what
    the operator is asked now, as JSON ``{"instruction", "t_s"}``; empty when nothing waits) in its metadata.

    The time left changes at every planned reading done; it rides in the next reading's transaction and
    has a transaction of its own only when none was written for ``ETA_EVERY_S`` of wall time (a run in real
    time: every reading; a simulated one: one durable write per reading, not two)."""

    ETA_EVERY_S = 1.0

    def __init__(self, store: RunStore, eta: Eta | None = None, now: Callable[[], float] = time.monotonic):
        self.store = store
        self.eta = eta  # subscribed before this writer: the time left it keeps in the store's meta
        self.current: dict[str, Any] = {}
        self.now = now
        self._eta_text: str | None = None
        self._eta_at = -1e9  # when the time left last went into a transaction (wall clock)
        store.keep_meta_also(self._kept)

    def _kept(self) -> dict[str, str]:
        """What every reading's and event's transaction also writes."""
        kept = {"current": json.dumps(self.current, sort_keys=True)}
        if self._eta_text is not None:
            kept[ETA_KEY] = self._eta_text
            self._eta_at = self.now()
        return kept

    def __call__(self, name: str, doc: dict[str, Any]) -> None:
        if name == "readings":
            self.store.add_readings(doc["readings"])
        elif name == "event":
            self.store.add_event(doc["t_s"], doc["kind"], doc["message"], doc["instrument"])
        elif name == "start":
            if doc.get("descriptions"):  # what each instrument's stored quantities are (drivers/interfaces.py)
                self.store.add_descriptions(doc["descriptions"])
            generation = self.store.meta().get("generation", "0")
            if "t_s" in doc and generation.isdigit():  # which attempt this start (0, +1 per resume) begins with
                self.store.add_start(int(generation), doc["t_s"])
            self.store.set_meta({"planned_readings": str(doc["planned"]),
                                 ETA_KEY: f"{self.eta.eta_s():.1f}" if self.eta is not None else ""})
            if self.store.meta().get(OPERATOR_WAITING):  # a run killed while it waited: nothing waits now
                self.store.set_meta({OPERATOR_WAITING: ""})
        elif name == "state":
            self.store.set_meta({"engine_state": doc["state"], **({ETA_KEY: self._eta_text} if self._eta_text else {})})
        elif name == "attempt":
            self.current = {**doc["label"], "plan_index": doc["index"]}
        elif name == "done" and self.eta is not None:
            self._eta_text = f"{self.eta.eta_s():.1f}"
            if self.now() - self._eta_at >= self.ETA_EVERY_S:
                self.store.set_meta({ETA_KEY: self._eta_text})
                self._eta_at = self.now()
        elif name == "operator":
            asked = doc["instruction"]
            self.store.set_meta({OPERATOR_WAITING: json.dumps({"instruction": asked, "t_s": doc["t_s"], "step": doc.get("step")},
                                                                ensure_ascii=False)
                                 if asked else ""})


class _Gone:
    """Where the progress goes once the console is gone: nowhere."""

    def write(self, text: str) -> int:
        return len(text)

    def flush(self) -> None:
        pass


def _hms(seconds: float) -> str:
    seconds = max(0, int(round(seconds)))
    h, rem = divmod(seconds, 3600)
    m, s = divmod(rem, 60)
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


WHERE = (("target_deg", "target {:g}°"), ("run", "run {}"), ("direction", "direction {}"), ("point", "point {}"),
         ("station", "station {}"), ("mount", "mount {}"), ("seating", "seating {}"))


def describe(label: dict[str, Any]) -> str:
    """Where the run is, in words: target, run and direction (or point and station, mount)."""
    return ", ".join(text.format(label[key]) for key, text in WHERE if key in label)


class ConsoleProgress:
    """Done / planned, where the run is, the time left and the faults so far. On a terminal a bar
    that redraws; otherwise (a log, a service) one line whenever another 10 % is done or 60 s of wall
    time have passed, and one at the end."""

    def __init__(self, stream: TextIO | None = None, bar: bool | None = None, every_s: float = 60.0,
                 now: Callable[[], float] = time.monotonic, virtual_clock: bool = False, eta: Eta | None = None):
        self.eta = eta  # the walk's estimate (what the live page shows); None: the rate of this start
        self.stream = stream if stream is not None else sys.stderr
        self.virtual_clock = virtual_clock  # the time left is the bench's, not the wall's: said so
        self.bar = self.stream.isatty() if bar is None else bar
        self.every_s = every_s
        self.now = now
        self.planned = 0
        self.done = 0
        self._first_done = 0
        self._t0_s: float | None = None
        self._last_line_s = 0.0
        self._last_decile = -1
        self.faults = 0
        self.where = ""
        self.clock_s = 0.0
        self._shown_done = -1  # the done count of the last line written (a log's last line is not repeated)

    def eta_s(self) -> float | None:
        """Time left: the walk's estimate, else at the rate of this start (the run's own clock:
        virtual for a simulated run)."""
        if self.eta is not None:
            return self.eta.eta_s()
        taken = self.done - self._first_done
        if self._t0_s is None or taken <= 0:
            return None
        rate = (self.clock_s - self._t0_s) / taken
        return rate * max(0, self.planned - self.done)

    def line(self) -> str:
        pct = 100.0 * self.done / self.planned if self.planned else 100.0
        eta = self.eta_s()
        return (f"readings {self.done}/{self.planned} ({pct:.0f} %)" + (f" · {self.where}" if self.where else "")
                + (f" · about {_hms(eta)} left" + (" on the virtual clock" if self.virtual_clock else "")
                   if eta is not None else "")
                + f" · {self.faults} fault{'' if self.faults == 1 else 's'}")

    def __call__(self, name: str, doc: dict[str, Any]) -> None:
        try:
            self._update(name, doc)
        except OSError:  # the terminal is gone (SIGHUP, a closed SSH session: EIO): the store has it all
            self.stream = _Gone()

    def _update(self, name: str, doc: dict[str, Any]) -> None:
        if name == "start":
            self.planned, self.done = doc["planned"], doc["done"]
            self._first_done, self._t0_s = doc["done"], doc["t_s"]
            self._last_line_s = self.now()
            self._last_decile = int(10 * self.done / self.planned) if self.planned else 10
        elif name == "attempt":
            self.where = describe(doc["label"])
        elif name == "done":
            self.done, self.faults, self.clock_s = doc["done"], doc["faults"], doc["t_s"]
            self._show()
        elif name == "stop":
            if self.bar:
                self.stream.write("\r" + self.line() + "\n")
            elif self.done != self._shown_done:
                self.stream.write("rtcal: " + self.line() + "\n")
            self.stream.flush()

    def _show(self) -> None:
        if self.bar:
            self.stream.write("\r\033[K" + self.line())
            self.stream.flush()
            return
        decile = int(10 * self.done / self.planned) if self.planned else 10
        if decile > self._last_decile or self.now() - self._last_line_s >= self.every_s:
            self._last_decile, self._last_line_s, self._shown_done = decile, self.now(), self.done
            self.stream.write("rtcal: " + self.line() + "\n")  # a log's line says whose it is
            self.stream.flush()
