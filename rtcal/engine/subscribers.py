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
import os
import sys
import time
from typing import Any, Callable, TextIO

from rtcal.store.runstore import RunStore

OPERATOR_WAITING = "operator_waiting"  # the store's meta key the live view reads
ETA_KEY = "eta_s"  # the store's meta key of the time left (the live view shows what the log says)
ETA_AT_KEY = "eta_at"  # … and of when it was estimated (JSON: run clock, wall clock UTC, the solving it holds)


SOLVE_FIXED_S = 10.0
"""The solving and writing after the last reading that does not grow with the plan: imports, the report and
its figures (README's Performance: about 4 s of CPU, the wall on a loaded computer about twice that)."""
SOLVE_PER_READING_S = 0.004
"""… and what each planned reading adds (README's Performance: 1.1–1.8 ms of CPU per length, twice on the wall)."""


def solve_estimate_s(planned: int) -> float:
    """The solving and writing after the last reading, estimated from the plan's size alone."""
    return SOLVE_FIXED_S + SOLVE_PER_READING_S * max(planned, 0)


class Eta:
    """The time left: one estimate for the console and the live page (through the store).

    The plan's remaining machine time as the walk counts it (:attr:`PlanWalk.entry_s`: motions,
    settles, samples), times the pace this start has kept against the walk: the walk's own pace (1)
    counts as ``PRIOR_S`` of walked time, so the first estimate is the plan's walked duration and the
    measured pace takes over within the first readings (on a bench whose motions are not the walk's
    speeds the walk alone is 2–3× off). Given each entry's motions (``motion_s``:
    :attr:`PlanWalk.entry_motion_s`) the motions and the rest (settles, samples: the procedure's own
    times) have a pace each, fitted by least squares over the entries done (each weighted by 1 / its
    walked time, so that without motions it is the ratio of the sums): where one entry in 24 holds a long
    return the one pace was right only at whole cycles, the estimate rising within each. Each operator step counts at its stated duration until it
    begins (``operator_step``); from then on the step is the person's, and the time until their Done
    (``operator``), like time paused, is neither counted again nor taken into the pace. A simulated
    operator on a real clock (``operator_timed`` False) does its steps at once: they count nothing. The
    solving and writing after the last reading (``after_s``, from the plan's size) is added. A resume
    walks only the entries still to take. The pending totals are running totals: a document costs O(1),
    whatever the plan's length."""

    PRIOR_S = 1.0

    def __init__(self, entry_s: dict[int, tuple[float, float]], virtual_clock: bool, operator_timed: bool = True,
                 after_s: float = 0.0, motion_s: dict[int, float] | None = None):
        self.entry_s = entry_s
        self.motion_s = motion_s or {}
        self.virtual_clock = virtual_clock  # a virtual clock counts an operator step's stated time itself
        self.operator_timed = operator_timed
        self.after_s = after_s
        self.pending = set(entry_s)
        self._pending_machine_s = math.fsum(total - operator for total, operator in entry_s.values())
        self._pending_operator_s = math.fsum(operator for _, operator in entry_s.values())
        self._begun_s = 0.0  # stated operator time of steps begun since the last entry done: no longer to come
        self._pending_motion_s = math.fsum(self.motion_s.get(k, 0.0) for k in entry_s)
        self.machine_s = 0.0  # measured machine time of the entries done in this start …
        self.walked_s = 0.0  # … and the walk's for them
        self._fit = [0.0] * 5  # Σ m²/t, Σ m·d/t, Σ d²/t, Σ m·s/t, Σ d·s/t: walked motion m, rest d, t = m + d, spent s
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
        elif name == "operator_step":
            self._begun_s += float(doc.get("seconds") or 0.0)
        elif name == "operator":
            if doc["instruction"]:
                self._asked_at = doc["t_s"]
            else:
                self._resumed(doc["t_s"], self._asked_at)
                self._asked_at = None
        elif name == "done":
            self._done(doc)

    def _done(self, doc: dict[str, Any]) -> None:
        k = doc["index"]
        if k in self.pending and self._t_s is not None:
            self.pending.discard(k)
            total, operator = self.entry_s[k]
            motion = self.motion_s.get(k, 0.0)
            self._pending_machine_s -= total - operator
            self._pending_operator_s -= operator
            self._pending_motion_s -= motion
            spent = max(0.0, doc["t_s"] - self._t_s - self._excluded_s - (operator if self.virtual_clock else 0.0))
            self.machine_s += spent
            self.walked_s += total - operator
            walked = total - operator
            if walked > 0:
                m, d = min(max(motion, 0.0), walked), walked - min(max(motion, 0.0), walked)
                for i, add in enumerate((m * m, m * d, d * d, m * spent, d * spent)):
                    self._fit[i] += add / walked
        self._t_s, self._excluded_s, self._begun_s = doc["t_s"], 0.0, 0.0

    def paces(self) -> tuple[float, float]:
        """Measured time per walked second of the motions (within 0–5: a simulated drive moves at once) and
        of the rest (within 0.05–5), each drawn to the walk's 1 with the weight of ``PRIOR_S``."""
        mm, md, dd, ms, ds = self._fit
        a, c, y1, y2 = mm + self.PRIOR_S, dd + self.PRIOR_S, ms + self.PRIOR_S, ds + self.PRIOR_S
        det = a * c - md * md  # > 0: the prior makes the normal matrix positive definite
        return (min(max((y1 * c - md * y2) / det, 0.0), 5.0), min(max((a * y2 - md * y1) / det, 0.05), 5.0))

    def measuring_s(self) -> float:
        """The time left to the last reading."""
        if not self.pending:  # what the running totals hold beyond this is rounding
            return 0.0
        operator = max(self._pending_operator_s - self._begun_s, 0.0) if self.operator_timed else 0.0
        motion_pace, rest_pace = self.paces()
        motion = min(max(self._pending_motion_s, 0.0), max(self._pending_machine_s, 0.0))
        return motion_pace * motion + rest_pace * (max(self._pending_machine_s, 0.0) - motion) + operator

    def eta_s(self) -> float:
        """The time left to the results: to the last reading, then the solving and writing."""
        return self.measuring_s() + self.after_s


class StoreWriter:
    """Commits each ``readings`` and ``event`` document to the run's store before the engine goes on,
    and keeps ``engine_state``, ``planned_readings``, ``current``, the time left and ``operator_waiting`` (what
    the operator is asked now, as JSON ``{"instruction", "t_s"}``; empty when nothing waits) in its metadata.

    The time left (``eta_s``) goes with when it was estimated (``eta_at``: the run's clock, the wall
    clock's UTC seconds, and the solving and writing it holds), so the live page counts it down and names
    the end time. It changes at every planned reading done; it rides in the next reading's transaction
    and has a transaction of its own only when none was written for ``ETA_EVERY_S`` of wall time (a run in
    real time: every reading; a simulated one: one durable write per reading, not two). An operator step
    that begins or is confirmed writes it at once."""

    ETA_EVERY_S = 1.0

    def __init__(self, store: RunStore, eta: Eta | None = None, now: Callable[[], float] = time.monotonic,
                 wall: Callable[[], float] = time.time):
        self.store = store
        self.eta = eta  # subscribed before this writer: the time left it keeps in the store's meta
        self.current: dict[str, Any] = {}
        self.now = now
        self.wall = wall
        self._eta_text: dict[str, str] | None = None
        self._eta_at = -1e9  # when the time left last went into a transaction (wall clock)
        store.keep_meta_also(self._kept)

    def _kept(self) -> dict[str, str]:
        """What every reading's and event's transaction also writes."""
        kept = {"current": json.dumps(self.current, sort_keys=True)}
        if self._eta_text is not None:
            kept.update(self._eta_text)
            self._eta_at = self.now()
        return kept

    def _estimate(self, t_s: float) -> dict[str, str]:
        """The time left now (run clock ``t_s``), as the store's meta holds it."""
        assert self.eta is not None
        self._eta_text = {ETA_KEY: f"{self.eta.eta_s():.1f}", ETA_AT_KEY: json.dumps(
            {"t_s": round(t_s, 3), "utc": round(self.wall(), 3), "after_s": round(self.eta.after_s, 1)})}
        return self._eta_text

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
                                 **(self._estimate(doc.get("t_s", 0.0)) if self.eta is not None else {ETA_KEY: ""})})
            if self.store.meta().get(OPERATOR_WAITING):  # a run killed while it waited: nothing waits now
                self.store.set_meta({OPERATOR_WAITING: ""})
        elif name == "state":
            self.store.set_meta({"engine_state": doc["state"], **(self._estimate(doc["t_s"]) if self._eta_text else {})})
        elif name == "attempt":
            self.current = {**doc["label"], "plan_index": doc["index"]}
        elif name == "done" and self.eta is not None:
            self._estimate(doc["t_s"])
            if self.now() - self._eta_at >= self.ETA_EVERY_S:
                self.store.set_meta(self._estimate(doc["t_s"]))
                self._eta_at = self.now()
        elif name == "operator_step" and self.eta is not None:
            self.store.set_meta(self._estimate(doc["t_s"]))
        elif name == "stop" and doc.get("state") == "measured" and self.eta is not None:  # the last reading's, whole
            self.store.set_meta(self._estimate(doc["t_s"]))
        elif name == "operator":
            asked = doc["instruction"]
            self.store.set_meta({OPERATOR_WAITING: json.dumps({"instruction": asked, "t_s": doc["t_s"], "step": doc.get("step")},
                                                                ensure_ascii=False)
                                 if asked else "", **(self._estimate(doc["t_s"]) if self.eta is not None else {})})


class _Gone:
    """Where the progress goes once the console is gone: nowhere."""

    def write(self, text: str) -> int:
        return len(text)

    def flush(self) -> None:
        pass


def _columns(stream: Any) -> int | None:
    """The terminal's width now; None (the line uncut) when it cannot be asked or says 0 (a new
    pseudo-terminal, `script`, a serial console), where a bar cut to 0 columns would show nothing."""
    try:
        return os.get_terminal_size(stream.fileno()).columns or None
    except (OSError, ValueError, AttributeError):
        return None


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
    """Done / planned, where the run is, the time left (with the clock time it ends on a real clock) and the
    faults so far. On a terminal a drawn bar (tqdm) that redraws; otherwise (a log, a service) one line
    whenever another 10 % is done or 60 s of wall time have passed, and one at the end. The solving and
    writing the time left holds is said once, at the start."""

    def __init__(self, stream: TextIO | None = None, bar: bool | None = None, every_s: float = 60.0,
                 now: Callable[[], float] = time.monotonic, virtual_clock: bool = False, eta: Eta | None = None,
                 wall: Callable[[], float] = time.time):
        self.eta = eta  # the walk's estimate (what the live page shows); None: the rate of this start
        self.stream = stream if stream is not None else sys.stderr
        self.virtual_clock = virtual_clock  # the time left is the bench's, not the wall's: said so
        self.bar = self.stream.isatty() if bar is None else bar
        self.every_s = every_s
        self.now = now
        self.wall = wall
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
        self._drawn: Any = None  # the terminal's bar (tqdm), once drawn

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

    def tail(self) -> str:
        """Where the run is, the time left and when it ends, the faults."""
        eta = self.eta_s()
        left = ""
        if eta is not None:
            left = f"about {_hms(eta)} left" + (" on the virtual clock" if self.virtual_clock else
                                                time.strftime(", ends about %H:%M", time.localtime(self.wall() + eta)))
        return " · ".join(x for x in (self.where, left, f"{self.faults} fault{'' if self.faults == 1 else 's'}") if x)

    def line(self) -> str:
        pct = 100.0 * self.done / self.planned if self.planned else 100.0
        return f"readings {self.done}/{self.planned} ({pct:.0f} %) · {self.tail()}"

    def __call__(self, name: str, doc: dict[str, Any]) -> None:
        try:
            self._update(name, doc)
        except OSError:  # the terminal is gone (SIGHUP, a closed SSH session: EIO): the store has it all
            self.stream = _Gone()
            self._drawn = None

    def _update(self, name: str, doc: dict[str, Any]) -> None:
        if name == "start":
            self.planned, self.done = doc["planned"], doc["done"]
            self._first_done, self._t0_s = doc["done"], doc["t_s"]
            self._last_line_s = self.now()
            self._last_decile = int(10 * self.done / self.planned) if self.planned else 10
            if self.eta is not None and self.eta.after_s > 0:
                self.stream.write(f"rtcal: the time left includes about {_hms(self.eta.after_s)} to solve and write the "
                                  f"results after the last reading (estimated from the plan's {self.planned} readings)\n")
                self.stream.flush()
        elif name == "attempt":
            self.where = describe(doc["label"])
        elif name == "done":
            self.done, self.faults, self.clock_s = doc["done"], doc["faults"], doc["t_s"]
            self._show()
        elif name == "stop":
            if self.bar:
                self._draw()
                self._drawn.close()
                self._drawn = None
            elif self.done != self._shown_done:
                self.stream.write("rtcal: " + self.line() + "\n")
            self.stream.flush()

    def _draw(self) -> None:
        """The terminal's bar, redrawn: readings done of planned, the bar, then where, the time left and the faults."""
        if self._drawn is None:
            from tqdm import tqdm

            self._drawn = tqdm(total=max(self.planned, 1), initial=self.done, file=self.stream, mininterval=0.0,
                               bar_format="readings {n}/{total} ({percentage:.0f} %) |{bar:20}| {desc}")
        self._drawn.ncols = _columns(self.stream)
        self._drawn.n = self.done
        self._drawn.set_description_str(self.tail(), refresh=False)  # a terminal narrower than the line cuts its end
        self._drawn.refresh()

    def _show(self) -> None:
        if self.bar:
            self._draw()
            return
        decile = int(10 * self.done / self.planned) if self.planned else 10
        if decile > self._last_decile or self.now() - self._last_line_s >= self.every_s:
            self._last_decile, self._last_line_s, self._shown_done = decile, self.now(), self.done
            self.stream.write("rtcal: " + self.line() + "\n")  # a log's line says whose it is
            self.stream.flush()
