"""``rtcal catalog add | history | list``: a lab's catalogue of verified calibrations (rtcal/catalog)."""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path
from typing import Any

from rtcal.cli.common import EXIT_FAILED, EXIT_OK, EXIT_USAGE, UserError, json_text


def _open(args: argparse.Namespace, write: bool = False) -> Any:
    """The catalogue, read-only unless ``write`` (only `add` migrates it or creates its file)."""
    from rtcal.catalog.store import Catalog, CatalogUsage

    try:
        return Catalog(args.db, write=write)
    except CatalogUsage as exc:
        raise UserError(str(exc)) from None


def cmd_catalog(args: argparse.Namespace) -> int:
    from rtcal.catalog.store import CatalogError

    try:
        return int({"add": _add, "history": _history, "list": _list}[args.catalog_command](args))
    except CatalogError as exc:
        print(f"rtcal: {exc}", file=sys.stderr)
        return EXIT_FAILED


def _add(args: argparse.Namespace) -> int:
    """Verify every run first (a refused one: exit 1 or 2, nothing of it written), refuse one that calibrated
    nothing unless --allow-simulated, then one transaction each."""
    from rtcal.catalog.entry import RunRefused, entry_of, marks, refuse_simulated, verified

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
    with _open(args, write=True) as cat:
        for entry in entries:
            added = cat.add(entry)
            mark = f" [{marks(entry)}]" if marks(entry) else ""
            print(f"{entry['run_id']} {entry['serial_number']} {entry['axis']} {entry['measured_utc']}{mark}: "
                  f"{'added to' if added else 'already in'} {cat.name}")
    return EXIT_OK


def _history(args: argparse.Namespace) -> int:
    from rtcal.catalog.entry import marks
    from rtcal.catalog.history import e_text as history_e_text
    from rtcal.catalog.history import entry_json, history_document

    from rtcal.catalog.history import by_axis

    with _open(args) as cat:
        rows = [r for rs in by_axis(cat.history(args.serial, args.axis)).values() for r in rs]
    if not rows:
        print(f"rtcal: no calibration of {args.serial}{' axis ' + args.axis if args.axis else ''} in {cat.name}",
              file=sys.stderr)
        return EXIT_FAILED
    doc = history_document(rows)
    if args.plot:
        _plot(rows, Path(args.plot))
    if args.json:
        entries = [entry_json(r) for r in rows]
        for e, r in zip(entries, rows):  # what it is besides a calibration: simulated, unsigned
            e["simulated"], e["signature"], e["marks"] = r["simulated"], r["signature"], marks(r)
        for e in entries:  # each entry carries its axis's pairs role and trend
            axis = doc[e["axis"]]
            e["as_found_of"] = next((p["as_left"] for p in axis["pairs"] if p["as_found"] == e["run_id"]), None)
            e["as_left_of"] = next((p["as_found"] for p in axis["pairs"] if p["as_left"] == e["run_id"]), None)
            e["trend"] = axis["trend"]
        print(json_text(entries))
        return EXIT_OK
    print(f"{'measured (UTC)':26} {'axis':5} {'method':22} {'E ± U (″)':>16} {'verdict':10} {'certificate':20} marks")
    for r in rows:
        e_text = history_e_text(r)
        print(f"{r['measured_utc'][:25]:26} {r['axis']:5} {r['method'][:22]:22} {e_text:>16} {r['verdict']:10} "
              f"{r['certificate_number'][:20]:20} {marks(r)}".rstrip())
    if any(r["simulated"] for r in rows):
        print(f"{sum(1 for r in rows if r['simulated'])} of {len(rows)} entries are SIMULATED (added with "
              "--allow-simulated): not calibrations")
    for axis, d in doc.items():
        t = d["trend"]
        for p in d["pairs"]:
            print(f"axis {axis}: as found {p['as_found'][:12]} → as left {p['as_left'][:12]}: E changed "
                  f"{p['E_change_arcsec']}″")
        if t["E_trend_arcsec_per_year"] is None:
            print(f"axis {axis}: E's trend needs two runs at different times outside as-left runs ({t['runs_fitted']})")
        else:
            print(f"axis {axis}: E's trend {t['E_trend_arcsec_per_year']:+.3f} ± {t['E_trend_U_arcsec_per_year']:.3f} ″/year "
                  f"({t['runs_fitted']} runs); reaches its limit {t['E_limit_arcsec']}″: {t['E_reaches_limit']}")
        print(f"axis {axis}: next due {d['next_due'] or '– (no entry has a time rtcal can read)'} (method: {t['method']})")
    return EXIT_OK


def _plot(rows: list[dict[str, Any]], path: Path) -> None:
    """E ± U over time per axis, with its acceptance limit."""
    import math

    from matplotlib.dates import AutoDateLocator, ConciseDateFormatter, date2num

    from rtcal.catalog.history import by_axis, time_of
    from rtcal.deliverables.figures import plt  # every text drawn as written (no mathtext: a serial may hold `$`)

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for axis, axis_rows in sorted(by_axis(rows).items()):
        rs = [r for r in axis_rows if time_of(r) is not None and r["E_arcsec"] is not None and math.isfinite(r["E_arcsec"])]
        ax.errorbar(date2num([time_of(r) for r in rs]), [r["E_arcsec"] for r in rs],
                    yerr=[r["E_U_arcsec"] if r["E_U_arcsec"] and math.isfinite(r["E_U_arcsec"]) else 0 for r in rs],
                    fmt="o-", capsize=3, label=f"axis {axis}: E ± U (k = 2)")
        limits = [r["E_limit_arcsec"] for r in rs if r["E_limit_arcsec"] is not None and math.isfinite(r["E_limit_arcsec"])]
        if limits:
            ax.axhline(limits[-1], color="red", linestyle="--", label=f"axis {axis}: E's limit {limits[-1]:g}″")
    locator = AutoDateLocator()
    ax.xaxis.set_major_locator(locator)
    ax.xaxis.set_major_formatter(ConciseDateFormatter(locator))  # dates a person reads, minutes to decades
    ax.set_ylabel("E (arcsec)")
    ax.set_xlabel("measured (UTC)")
    ax.set_title(f"{rows[0]['serial_number']}: ISO 230-2 E over time")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _list(args: argparse.Namespace) -> int:
    from rtcal.catalog.entry import marks
    from rtcal.catalog.history import fleet

    with _open(args) as cat:
        rows = cat.machines()
    machines = fleet(rows)
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
    print(f"{'serial number':20} {'axis':5} {'machine':30} {'runs':>4} {'last (UTC)':11} {'verdict':10} {'next due':11} marks")
    for m in machines:
        simulated = f"{m['simulated_entries']} of {m['calibrations']} SIMULATED" if m["simulated_entries"] else ""
        shown = "; ".join(x for x in (m["marks"], simulated) if x)
        print(f"{m['serial_number'][:20]:20} {m['axis'][:5]:5} {m['machine'][:30]:30} {m['calibrations']:>4} "
              f"{m['last_utc'][:10]:11} {m['verdict']:10} {m['next_due'] or '–':11} {shown}".rstrip())
    return EXIT_OK


def add_catalog(sub: Any) -> None:
    cat = sub.add_parser("catalog", help="a lab's catalogue of verified calibrations (SQLite by default, or PostgreSQL): "
                                         "add runs, a machine's history, the fleet")
    cat_sub = cat.add_subparsers(dest="catalog_command", required=True)
    db_help = ("the catalogue: postgresql://user:password@host:port/db or a SQLite file (default: $RTCAL_CATALOG, else "
               "catalog.sqlite under the user's data folder)")
    add = cat_sub.add_parser("add", help="verify finished runs (as `rtcal verify`) and add each in one transaction; a run "
                                         "already there changes nothing")
    add.add_argument("runs", nargs="+", metavar="RUN", help="run directories")
    add.add_argument("--db", help=db_help)
    add.add_argument("--allow-simulated", action="store_true",
                     help="also file a run that calibrated nothing (simulated in process, on `rtcal sim serve`, or "
                          "--rehearse): refused without it; every listing then marks it SIMULATED")
    hist = cat_sub.add_parser("history", help="a machine axis's calibrations oldest first, as-found/as-left pairs, E's "
                                              "trend and the date it reaches its limit")
    hist.add_argument("--serial", required=True, metavar="SN", help="the machine's serial number")
    hist.add_argument("--axis", help="one axis (default: every axis)")
    hist.add_argument("--db", help=db_help)
    hist.add_argument("--json", action="store_true", help="print a JSON list of the entries")
    hist.add_argument("--plot", metavar="FILE", help="draw E ± U over time with the limit into FILE (PNG)")
    lst = cat_sub.add_parser("list", help="every machine axis: its last calibration, verdict and next due date")
    lst.add_argument("--db", help=db_help)
    lst.add_argument("--json", action="store_true", help="print a JSON list")
    for p in (add, hist, lst):
        p.set_defaults(func=cmd_catalog)
