"""``rtcal catalog``: a lab's catalogue of verified calibrations and its programme (rtcal/catalog):
add, history, list, due, used-by, reassess, verify, policy, retire, hours, sync, migrate."""

from __future__ import annotations

import argparse
import json
import os
import socket
import sys
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

from rtcal.cli.common import EXIT_FAILED, EXIT_OK, EXIT_USAGE, UserError, json_text, one_line


def _open(args: argparse.Namespace, write: bool = False) -> Any:
    """The catalogue, read-only unless ``write`` (`add` and the commands that record migrate it or create its file)."""
    from rtcal.catalog.store import Catalog, CatalogUsage

    try:
        return Catalog(args.db, write=write)
    except CatalogUsage as exc:
        raise UserError(str(exc)) from None


def cmd_catalog(args: argparse.Namespace) -> int:
    from rtcal.catalog.store import CatalogError, CatalogUsage

    try:
        return int(COMMANDS[args.catalog_command](args))
    except CatalogUsage as exc:
        raise UserError(str(exc)) from None
    except CatalogError as exc:
        print(f"rtcal: {exc}", file=sys.stderr)
        return EXIT_FAILED


def _who(args: argparse.Namespace) -> str:
    from rtcal.catalog.store import os_user

    who = " ".join((getattr(args, "by", None) or "").split())
    if len(who) > 100 or any(ord(c) < 32 for c in who):
        raise UserError("--by: a name of at most 100 characters, no control characters")
    return who or os_user()


def _reason(args: argparse.Namespace, what: str, required: bool) -> str:
    reason = " ".join((args.reason or "").split())
    if required and not reason:
        raise UserError(f"--reason: {what} is recorded with why (who and when are taken from the system or --by)")
    if len(reason) > 2000:
        raise UserError("--reason: at most 2000 characters")
    return reason


def _date(text: str | None, option: str) -> str | None:
    if text is None:
        return None
    try:
        return datetime.fromisoformat(text).replace(tzinfo=timezone.utc).date().isoformat()
    except ValueError:
        raise UserError(f"{option} {text[:40]!r}: not a date (YYYY-MM-DD)") from None


def _outbox(args: argparse.Namespace, location: str | None) -> Path | None:
    """The rig's outbox for a PostgreSQL catalogue (a network one may be away); none for a SQLite file."""
    from rtcal.catalog.outbox import default_outbox
    from rtcal.catalog.store import default_location

    if getattr(args, "no_outbox", False) or "postgres" not in (location or default_location()).split("://")[0]:
        return None
    return default_outbox()


def _add(args: argparse.Namespace) -> int:
    """Verify every run first (a refused one: exit 1 or 2, nothing of it written), refuse one that calibrated
    nothing unless --allow-simulated, then one transaction each."""
    from rtcal.catalog.entry import RunRefused, entry_of, marks, refuse_simulated, verified
    from rtcal.catalog.history import certificate_words
    from rtcal.catalog.outbox import file_entry
    from rtcal.catalog.store import safe_name, database_url

    who, site = _who(args), _place(args.site, "RTCAL_SITE", "--site", "")
    rig = _place(args.rig, "RTCAL_RIG", "--rig", socket.gethostname())
    entries = []
    for run in args.runs:
        try:
            results, signature = verified(Path(run))
            if not args.allow_simulated:
                refuse_simulated(Path(run), results)
            entries.append(entry_of(Path(run), results, signature))
        except RunRefused as exc:
            print(f"rtcal: catalog add refused: {exc}", file=sys.stderr)
            return EXIT_USAGE if exc.code == 2 else EXIT_FAILED
    superseding = [e for e in entries if e["replaces"]]
    reason = _reason(args, f"a certificate that replaces another ({superseding[0]['replaces']})", bool(superseding)) \
        if superseding else _reason(args, "", False)
    if superseding:
        with _open(args, write=True) as cat:
            for e in superseding:
                old = [r for r in cat.by_certificate(e["replaces"]) if r["run_id"] != e["run_id"]]
                if not old:
                    raise UserError(f"{e['run_dir']}: metadata.replaces names certificate {e['replaces']!r}, which is not "
                                    f"in {cat.name}: add that one first, or correct the number")
                e["supersedes"] = old[-1]["run_id"]
    name = safe_name(database_url(args.db, create=True))
    outbox = _outbox(args, args.db)
    for e in entries:
        e.update(site=site, rig=rig, added_by=who)
        state, why = file_entry(args.db, e, who, reason, outbox)
        what = f"{certificate_words(e)} {e['serial_number']} {e['axis']}"
        if state == "waiting":
            print(f"rtcal: {why}; {what} waits in the outbox {outbox} (`rtcal catalog sync` sends it)", file=sys.stderr)
            return EXIT_FAILED
        mark = f" [{marks(e)}]" if marks(e) else ""
        print(f"{what}{mark}{' (replaces ' + e['replaces'] + ')' if e['replaces'] else ''}: "
              f"{'added to' if state == 'added' else 'already in'} {name}")
    return EXIT_OK


def check_location(location: str) -> None:
    """A catalogue URL `rtcal run --catalog` can use, checked before the run (UserError, exit 2)."""
    from rtcal.catalog.store import CatalogUsage, database_url

    try:
        if "://" in location and not location.startswith("sqlite"):  # (a SQLite file is made by the first add)
            database_url(location, create=False)
    except CatalogUsage as exc:
        raise UserError(f"--catalog: {exc}") from None


def file_finished_run(run_dir: Path, location: str, allow_simulated: bool = False) -> int:
    """`rtcal run --catalog URL`: the finished run added as `catalog add` adds it, then the rig's outbox
    sent (a catalogue out of reach: the run waits in the outbox, exit 1)."""
    args = argparse.Namespace(db=location, runs=[str(run_dir)], site=None, rig=None, by=None, reason=None, no_outbox=False,
                              allow_simulated=allow_simulated, catalog_command="add")
    try:
        code = cmd_catalog(args)
    except UserError as exc:
        print(f"rtcal: {exc}", file=sys.stderr)
        return EXIT_USAGE
    if code == EXIT_OK and _outbox(args, location) is not None:
        return cmd_catalog(argparse.Namespace(db=location, catalog_command="sync"))
    return code


def _place(given: str | None, env: str, option: str, default: str) -> str:
    text = " ".join((given if given is not None else os.environ.get(env, default)).split())
    if len(text) > 100 or any(ord(c) < 32 for c in text):
        raise UserError(f"{option} (or ${env}): at most 100 characters, no control characters")
    return text


def _sync(args: argparse.Namespace) -> int:
    from rtcal.catalog.outbox import default_outbox, sync

    outbox = default_outbox()
    found = sync(args.db, outbox)
    for line in found.refused:
        print(f"rtcal: refused, kept in {outbox / 'refused'}: {line}", file=sys.stderr)
    if found.failure:
        print(f"rtcal: {found.failure}; {found.waiting} entries still wait in {outbox}", file=sys.stderr)
        return EXIT_FAILED
    print(f"outbox {outbox}: {found.added} added, {found.already} already there"
          f"{', ' + str(len(found.refused)) + ' refused' if found.refused else ''}; none waiting")
    return EXIT_OK


def _migrate(args: argparse.Namespace) -> int:
    with _open(args, write=True) as cat:
        print(f"{cat.name}: at the newest revision")
    return EXIT_OK


# -- reading ----------------------------------------------------------------------------------------
def _due_of(cat: Any) -> Any:
    from rtcal.catalog.duelist import due_of

    return due_of(cat)


def _history(args: argparse.Namespace) -> int:
    from rtcal.catalog.entry import marks
    from rtcal.catalog.history import (by_axis, certificate_words, e_text, entry_json, history_document, location_lines,
                                       location_series)

    with _open(args) as cat:
        rows = [r for rs in by_axis(cat.history(args.serial, args.axis)).values() for r in rs]
        due = _due_of(cat)
        located = cat.location_errors_of([r["run_id"] for r in rows])
    if not rows:
        print(f"rtcal: no calibration of {args.serial}{' axis ' + args.axis if args.axis else ''} in {cat.name}",
              file=sys.stderr)
        return EXIT_FAILED
    doc = history_document(rows)
    dues = {axis: due(rows[0]["serial_number"], axis, rs) for axis, rs in by_axis(rows).items()}
    if args.plot:
        from rtcal.catalog.plot import plot_history

        print(plot_history(rows, Path(args.plot)))
    if args.json:
        entries = [entry_json(r) for r in rows]
        for e, r in zip(entries, rows):  # what it is besides a calibration: simulated, unsigned
            e["simulated"], e["signature"], e["marks"] = r["simulated"], r["signature"], marks(r)
        for e in entries:  # each entry carries its axis's pairs role, trend and next due date
            axis = doc[e["axis"]]
            e["as_found_of"] = next((p["as_left"] for p in axis["pairs"] if p["as_found"] == e["run_id"]), None)
            e["as_left_of"] = next((p["as_found"] for p in axis["pairs"] if p["as_left"] == e["run_id"]), None)
            e["superseded_by"] = axis["superseded"].get(e["run_id"])
            e["trend"] = axis["trend"]
            e["next_due"] = dues[e["axis"]]
        for e in entries:  # its ISO 230-7 location errors (the R-test's) by symbol: value, U, k
            e["location_errors_iso230_7"] = {x["symbol"]: {k: x[k] for k in ("axis", "value", "expanded_uncertainty",
                                                                             "coverage_factor")}
                                              for x in located if x["run_id"] == e["run_id"]}
        print(json_text(entries))
        return EXIT_OK
    print(f"{'measured (UTC)':17} {'axis':5} {'test':34} {'E ± U (″)':>16} {'verdict':10} {'state':9} certificate (marks)")
    replaced = {r["supersedes"]: r for r in rows if r.get("supersedes")}
    for r in rows:
        state = {"as_found": "as found", "as_left": "as left"}.get(r.get("state", ""), "–")
        note = f" (superseded by {replaced[r['run_id']]['certificate_number']})" if r["run_id"] in replaced else ""
        note += f" (replaces {r['replaces']})" if r.get("replaces") else ""
        note += f" [{marks(r)}]" if marks(r) else ""
        print(f"{r['measured_utc'][:16].replace('T', ' '):17} {r['axis'][:5]:5} {(r.get('test') or r['method'])[:34]:34} "
              f"{e_text(r):>16} {r['verdict']:10} {state:9} {r['certificate_number'] or '–'}{note}")
    for line in location_lines(location_series(rows, located)):
        print(line)
    if any(r["simulated"] for r in rows):
        print(f"{sum(1 for r in rows if r['simulated'])} of {len(rows)} entries are SIMULATED (added with "
              "--allow-simulated): not calibrations")
    for axis, d in doc.items():
        t = d["trend"]
        for p in d["pairs"]:
            found = {"certificate_number": p["as_found_certificate"], "measured_utc": p["as_found_utc"], "run_id": p["as_found"]}
            left = {"certificate_number": p["as_left_certificate"], "measured_utc": p["as_left_utc"], "run_id": p["as_left"]}
            change = "–" if p["E_change_arcsec"] is None else f"{p['E_change_arcsec']:+.2f}″"
            print(f"axis {axis}: as found {certificate_words(found)} → as left {certificate_words(left)}: E changed "
                  f"{change} ({p['how']})")
        if t["E_trend_arcsec_per_year"] is None:
            print(f"axis {axis}: E's trend needs two runs at different times outside as-left runs ({t['runs_fitted']})")
        else:
            print(f"axis {axis}: E's trend {t['E_trend_arcsec_per_year']:+.3f} ± {t['E_trend_U_arcsec_per_year']:.3f} ″/year "
                  f"({t['runs_fitted']} runs); its limit {t['E_limit_arcsec']}″: {t['E_reaches_limit']}")
        n = dues[axis]
        print(f"axis {axis}: next due {n['due'] or '–'} — {n['method']}: {n['data']}")
    return EXIT_OK


def _list(args: argparse.Namespace) -> int:
    from collections import Counter

    from rtcal.catalog.entry import marks
    from rtcal.catalog.history import fleet

    with _open(args) as cat:
        rows = cat.machines()
        machines = fleet(rows, _due_of(cat))
    if not machines:
        print(f"rtcal: {cat.name} holds no calibration yet (`rtcal catalog add RUN` adds one)", file=sys.stderr)
    by_id = {r["run_id"]: r for r in rows}
    per_axis = Counter((r["serial_number"], r["axis"]) for r in rows if r["simulated"])
    for m in machines:  # the last calibration's marks, and how many of the axis's entries calibrated nothing
        m["marks"] = marks(by_id[m["last_run_id"]])
        m["simulated_entries"] = per_axis[(m["serial_number"], m["axis"])]
    if args.json:
        print(json_text(machines))
        return EXIT_OK
    print(f"{'serial number':20} {'axis':5} {'machine':26} {'runs':>4} {'last':11} {'certificate':16} {'verdict':10} "
          "next due (method); marks")
    for m in machines:
        due = "retired" if m.get("due_retired") else (m["next_due"] or "–")
        simulated = f"{m['simulated_entries']} of {m['calibrations']} SIMULATED" if m["simulated_entries"] else ""
        shown = "; ".join(x for x in (m["marks"], simulated) if x)
        print(f"{m['serial_number'][:20]:20} {m['axis'][:5]:5} {m['machine'][:26]:26} {m['calibrations']:>4} "
              f"{m['last_utc'][:10]:11} {(m['last_certificate'] or '–')[:16]:16} {m['verdict']:10} {due} "
              f"({m['due_method']}){'; ' + shown if shown else ''}")
    return EXIT_OK


def _due(args: argparse.Namespace) -> int:
    from rtcal.catalog.duelist import due_list

    within = _days(args.within)
    with _open(args) as cat:
        found = due_list(cat, within, args.site, _due_of(cat))
    if args.json:
        print(json_text(found))
        return EXIT_OK
    if not found:
        print(f"nothing overdue or due within {within:g} days{' at ' + args.site if args.site else ''} in {cat.name}")
        return EXIT_OK
    print(f"{'due':11} {'status':20} {'site':12} {'serial number':20} {'axis':5} {'customer':24} method and data")
    for d in found:
        print(f"{d['next_due']:11} {d['status'][:20]:20} {(d['site'] or '–')[:12]:12} {d['serial_number'][:20]:20} "
              f"{d['axis'][:5]:5} {d['customer'][:24]:24} {d['due_method']}: {d['due_data']}")
    return EXIT_OK


def _days(text: str) -> float:
    t = text.strip().lower()
    try:
        value = float(t[:-1]) if t.endswith("d") else float(t)
    except ValueError:
        raise UserError(f"--within {text[:20]!r}: a number of days, e.g. 30d") from None
    if not 0 <= value <= 3650:
        raise UserError(f"--within {text[:20]}: 0 … 3650 days")
    return value


def _used_by(args: argparse.Namespace) -> int:
    since = _date(args.since, "--since")
    with _open(args) as cat:
        rows = cat.used_by(args.instrument, since)
        if not rows and not cat.used_by(args.instrument):
            raise UserError(_unknown(cat, args.instrument))
    if args.json:
        print(json_text(rows))
        return EXIT_OK
    print(f"{args.instrument}: used by {len(rows)} calibration{'s' if len(rows) != 1 else ''}"
          f"{' since ' + since if since else ''}")
    for r in rows:
        print(f"{r['measured_utc'][:10]} {r['certificate_number'] or '–':18} {r['serial_number'][:20]:20} {r['axis'][:5]:5} "
              f"{r['verdict']:10} as {r['role']} (its certificate {r['instrument_certificate'] or '–'}, due {r['instrument_due'] or '–'}; "
              f"applied: {r['correction']})")
    return EXIT_OK


def _unknown(cat: Any, instrument: str) -> str:
    if not cat.programme:
        return (f"{cat.name} records no instruments yet (revision before 0003): `rtcal catalog migrate --db …` brings it up "
                "and files the instruments of the entries it holds")
    near = cat.instrument_ids(instrument.split()[-1] if instrument.split() else "") or cat.instrument_ids()
    return (f"no calibration in {cat.name} used an instrument {instrument[:80]!r}: give its id as the runs name it"
            + (f" (e.g. {'; '.join(repr(n) for n in near[:4])})" if near else ""))


def _reassess(args: argparse.Namespace) -> int:
    from rtcal.catalog.reassess import load_certificate, reassess, report_lines

    calibration = _one_line(load_certificate, Path(args.certificate))
    if " ".join(args.instrument.split()) != calibration.instrument:
        raise UserError(f"{args.certificate}: its instrument is {calibration.instrument!r}, not {args.instrument!r}")
    reason = _reason(args, "a reassessment", True)
    since = _date(args.since, "--since")
    who = _who(args)
    with _open(args) as cat:
        if not cat.used_by(args.instrument):
            raise UserError(_unknown(cat, args.instrument))
    with _open(args, write=True) as cat:
        found = reassess(cat, calibration, since, who, reason, Path(args.out) if args.out else None, args.issue)
    if args.json:
        print(json_text(found))
    else:
        for line in report_lines(found):
            print(line)
    return EXIT_OK


def _verify(args: argparse.Namespace) -> int:
    import time

    from rtcal.catalog.verify import deep_problems

    t0 = time.perf_counter()
    with _open(args) as cat:
        found = cat.audit_check()
        problems = list(found.problems)
        if args.deep:
            problems += deep_problems(cat)
    for p in problems[:50]:
        print(f"rtcal: {p}", file=sys.stderr)
    if len(problems) > 50:
        print(f"rtcal: … and {len(problems) - 50} more", file=sys.stderr)
    print(f"{cat.name}: {found.rows} audit rows chained, {found.entries} entries against the rows that filed them"
          f"{' and their results and run folders' if args.deep else ''}: "
          f"{'all agree' if not problems else str(len(problems)) + ' problems'} ({time.perf_counter() - t0:.2f} s)")
    return EXIT_FAILED if problems else EXIT_OK


def _policy(args: argparse.Namespace) -> int:
    import hashlib

    from rtcal.catalog.intervals import load_policy
    from rtcal.catalog.schema import policies

    if args.file is None:
        with _open(args) as cat:
            found = cat.table(policies, "version")
        if not found:
            print(f"{cat.name}: no policy filed: every machine axis is due a year after its last calibration, or sooner "
                  "when E's trend reaches its limit")
            return EXIT_OK
        p = found[-1]
        print(f"# policy version {p['version']}, filed {p['at_utc'][:19]} by {p['who']}\n{p['text']}", end="")
        return EXIT_OK
    text = _one_line(load_policy, Path(args.file))
    reason = _reason(args, "a policy change", True)
    who = _who(args)
    with _open(args, write=True) as cat:
        version = len(cat.table(policies, "version")) + 1
        digest = hashlib.sha256(text.encode()).hexdigest()
        cat.record("policy", f"policy version {version}", who, reason, {"version": version, "sha256": digest},
                   rows=[(policies, {"version": version, "at_utc": _now(), "who": who, "text": text, "sha256": digest})])
    print(f"{cat.name}: policy version {version} filed ({args.file}; sha256 {digest[:16]}…)")
    return EXIT_OK


def _retire(args: argparse.Namespace) -> int:
    from rtcal.catalog.schema import normal_text, retirements

    reason = _reason(args, "a retirement", True)
    who = _who(args)
    serial, axis = normal_text(args.serial), normal_text(args.axis)
    with _open(args) as cat:
        if not cat.history(serial, axis):
            raise UserError(f"no calibration of {serial} axis {axis} in {cat.name}: nothing to retire")
    with _open(args, write=True) as cat:
        at = _now()
        cat.record("retire", f"{serial} axis {axis}", who, reason, {"serial_number": serial, "axis": axis},
                   rows=[(retirements, {"serial_number": serial, "axis": axis, "at_utc": at, "who": who, "reason": reason})])
    print(f"{serial} axis {axis}: retired on {at[:10]} ({reason}); its entries are kept")
    return EXIT_OK


def _hours(args: argparse.Namespace) -> int:
    import math

    from rtcal.catalog.schema import normal_text, usage

    serial = normal_text(args.serial)
    at = _date(args.at, "--at")
    if args.opcua:
        from drivers.errors import InstrumentError
        from drivers.opcua_counters import read_hours

        try:
            hours = read_hours(args.opcua)
        except InstrumentError as exc:
            print(f"rtcal: machine at {args.opcua}: {one_line(exc)}", file=sys.stderr)
            return EXIT_FAILED
        source = f"OPC UA {args.opcua} (OperationCounters)"
    else:
        if args.hours is None or not math.isfinite(args.hours) or not 0 <= args.hours <= 1e7:
            raise UserError("--hours: the machine's hours of use, 0 … 10 000 000 (or --opcua opc.tcp://HOST:PORT)")
        hours, source = args.hours, "given"
    when = f"{at}T00:00:00+00:00" if at else _now()
    with _open(args, write=True) as cat:
        cat.record("usage", serial, _who(args), _reason(args, "", False), {"hours": hours, "source": source},
                   rows=[(usage, {"serial_number": serial, "at_utc": when, "hours": hours, "source": source})])
    print(f"{serial}: {hours:g} h on {when[:10]} ({source})")
    return EXIT_OK


def _one_line(load: Any, path: Path) -> Any:
    """A file read and validated, or its first problem in one line (exit 2)."""
    from rtcal.procedure.yamlfile import FileProblems

    try:
        return load(path)
    except FileProblems as exc:
        more = f" (and {len(exc.problems) - 1} more)" if len(exc.problems) > 1 else ""
        raise UserError(f"{one_line(exc.problems[0])}{more}") from None


def _now() -> str:
    return datetime.now(timezone.utc).isoformat()


COMMANDS = {"add": _add, "history": _history, "list": _list, "due": _due, "used-by": _used_by, "reassess": _reassess,
            "verify": _verify, "policy": _policy, "retire": _retire, "hours": _hours, "sync": _sync, "migrate": _migrate}


def add_catalog(sub: Any) -> None:
    cat = sub.add_parser("catalog", help="a lab's catalogue of verified calibrations and its programme (SQLite by default, "
                                         "or PostgreSQL): add runs, histories, the fleet, due dates, reference instruments")
    cat_sub = cat.add_subparsers(dest="catalog_command", required=True)
    db_help = ("the catalogue: postgresql://user:password@host:port/db or a SQLite file (default: $RTCAL_CATALOG, else "
               "catalog.sqlite under the user's data folder)")
    by_help = "who does it (default: the operating system's user)"
    add = cat_sub.add_parser("add", help="verify finished runs (as `rtcal verify`) and add each in one transaction; a run "
                                         "already there changes nothing")
    add.add_argument("runs", nargs="+", metavar="RUN", help="run directories")
    add.add_argument("--site", help="the lab's site (default: $RTCAL_SITE, else none)")
    add.add_argument("--rig", help="the rig (default: $RTCAL_RIG, else this computer's name)")
    add.add_argument("--by", help=by_help)
    add.add_argument("--reason", help="why (required when a run's metadata.replaces names a certificate it supersedes)")
    add.add_argument("--allow-simulated", action="store_true",
                     help="also file a run that calibrated nothing (simulated in process, on `rtcal sim serve`, or "
                          "--rehearse): refused without it; every listing then marks it SIMULATED")
    add.add_argument("--no-outbox", action="store_true", help="PostgreSQL out of reach: fail (exit 1) rather than keep "
                                                              "the entry in the rig's outbox for `catalog sync`")
    hist = cat_sub.add_parser("history", help="a machine axis's calibrations oldest first, as-found/as-left pairs, E's "
                                              "trend, the date it reaches its limit, the next due date")
    hist.add_argument("--serial", required=True, metavar="SN", help="the machine's serial number")
    hist.add_argument("--axis", help="one axis (default: every axis)")
    hist.add_argument("--json", action="store_true", help="print a JSON list of the entries")
    hist.add_argument("--plot", metavar="FILE", help="draw E ± U over time with the trend, its band, the limit and the "
                                                     "failures into FILE (PNG)")
    lst = cat_sub.add_parser("list", help="every machine axis: its last calibration, verdict and next due date")
    lst.add_argument("--json", action="store_true", help="print a JSON list")
    due = cat_sub.add_parser("due", help="what is overdue and due soon across the fleet, each with its interval method")
    due.add_argument("--within", default="30d", help="due within this many days (default 30d)")
    due.add_argument("--site", help="one site")
    due.add_argument("--json", action="store_true", help="print a JSON list")
    used = cat_sub.add_parser("used-by", help="every calibration that used a reference instrument (its id as the runs "
                                              "name it)")
    used.add_argument("instrument", help="the instrument's id, e.g. 'Möller-Wedel ELCOMAT 3000 SN 1234'")
    used.add_argument("--since", metavar="DATE", help="measured on or after DATE (YYYY-MM-DD)")
    used.add_argument("--json", action="store_true", help="print a JSON list")
    re_ = cat_sub.add_parser("reassess", help="re-evaluate every run that used an instrument from its stored readings with "
                                              "the instrument's new calibration; list the certificates whose E, U or "
                                              "verdict change (--issue: write superseding certificates)")
    re_.add_argument("instrument", help="the instrument's id, as the runs name it")
    re_.add_argument("--certificate", required=True, metavar="NEW.yaml", help="its new calibration (docs/catalog.md)")
    re_.add_argument("--since", metavar="DATE", help="only runs measured on or after DATE")
    re_.add_argument("--reason", help="why (required)")
    re_.add_argument("--by", help=by_help)
    re_.add_argument("--issue", action="store_true", help="write a superseding certificate for each changed run (a new "
                                                          "folder each; the run and its certificate are kept)")
    re_.add_argument("--out", metavar="DIR", help="with --issue: the folder the new certificates go into (default: "
                                                 "beside each run folder)")
    re_.add_argument("--json", action="store_true", help="print the reassessment as JSON")
    ver = cat_sub.add_parser("verify", help="check the audit trail's chain and every entry against the row that filed it")
    ver.add_argument("--deep", action="store_true", help="also each entry's results text and its run folder's results.json")
    pol = cat_sub.add_parser("policy", help="file the interval policy (a YAML file; docs/catalog.md), or show the one filed")
    pol.add_argument("file", nargs="?", help="the policy file (none: show the current policy)")
    pol.add_argument("--reason", help="why (required to file one)")
    pol.add_argument("--by", help=by_help)
    ret = cat_sub.add_parser("retire", help="take a machine axis out of the programme (its entries are kept)")
    ret.add_argument("--serial", required=True, metavar="SN", help="the machine's serial number, as its entries name it")
    ret.add_argument("--axis", required=True, help="the axis to retire (e.g. C)")
    ret.add_argument("--reason", help="why (required)")
    ret.add_argument("--by", help=by_help)
    hrs = cat_sub.add_parser("hours", help="record a machine's hours of use (ILAC-G24 method 3): given, or read from its "
                                           "OPC UA server (OPC 40001-1 OperationCounters)")
    hrs.add_argument("--serial", required=True, metavar="SN", help="the machine's serial number, as its entries name it")
    hrs.add_argument("--hours", type=float, help="its hours of use")
    hrs.add_argument("--opcua", metavar="opc.tcp://HOST:PORT", help="read them from the machine's OPC UA server")
    hrs.add_argument("--at", metavar="DATE", help="when (default: now)")
    hrs.add_argument("--reason", help="a note")
    hrs.add_argument("--by", help=by_help)
    syn = cat_sub.add_parser("sync", help="send the entries waiting in this rig's outbox ($RTCAL_OUTBOX)")
    mig = cat_sub.add_parser("migrate", help="bring the catalogue to the newest revision (what `add` does first)")
    for p in (add, hist, lst, due, used, re_, ver, pol, ret, hrs, syn, mig):
        p.add_argument("--db", help=db_help)
        p.set_defaults(func=cmd_catalog)
