"""`rtcal view --catalog`: the fleet page (every machine axis, its last calibration, verdict and next
due date; a machine's history below it), read-only, from the catalogue database. Server-side HTML
(every text escaped), nothing from the internet; ``/api/catalog`` serves the same as strict JSON.
Served as the live page is (rtcal/live/web.py): a foreign Host header refused, so a page elsewhere
cannot read the lab's fleet, customers and serial numbers by DNS rebinding; a warning when bound
beyond this computer."""

from __future__ import annotations

import html
import json
import sys
import time
from typing import Any
from urllib.parse import quote

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import HTMLResponse, Response
from starlette.routing import Route

from rtcal.catalog.duelist import due_list, due_of
from rtcal.catalog.entry import marks
from rtcal.catalog.history import by_axis, e_text, fleet, trend
from rtcal.catalog.schema import normal_text
from rtcal.catalog.store import Catalog
from rtcal.live.web import bind, host_guard, serve, url_of, warn_exposed
from rtcal.results.io import finite

STYLE = ("body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}td,th{border:1px solid #bbb;"
         "padding:.3em .6em;text-align:left}.fail{color:#b00}.pass{color:#070}.undecided{color:#a60}"
         "tr.overdue td{background:#fde8e8}tr.soon td{background:#fff6df}small{color:#555}"
         ".marks{color:#b00;font-weight:bold}")


def _cell(value: Any) -> str:
    return "–" if value is None else html.escape(str(value))


def _page(location: str | None, serial: str | None, query: str | None = None, within: float = 30.0) -> str:
    with Catalog(location) as cat:
        due = due_of(cat)
        entries = cat.machines()
        machines = fleet(entries, due)
        soon = due_list(cat, within, None, due)
        history = [r for rs in by_axis(cat.history(serial)).values() for r in rs] if serial else []
        found = _search(cat, machines, query) if query else None
        name = cat.name
    last = {r["run_id"]: marks(r) for r in entries}  # the marks of each axis's last calibration
    rows = "".join(
        f'<tr class="machine"><td><a href="?serial={html.escape(quote(m["serial_number"]))}">{_cell(m["serial_number"])}</a></td>'
        f'<td>{_cell(m["axis"])}</td><td>{_cell(m["machine"])}</td><td>{_cell(m["customer"])}</td><td>{_cell(m["site"] or None)}</td>'
        f'<td>{m["calibrations"]}</td><td>{_cell(m["last_utc"][:10])}</td><td>{_cell(m["last_certificate"] or None)}</td>'
        f'<td class="{html.escape(m["verdict"])}">{_cell(m["verdict"])}</td><td>{html.escape(e_text(m))}</td>'
        f'<td class="due" title="{html.escape(str(m.get("due_data", "")))}">'
        f'{"retired" if m.get("due_retired") else _cell(m["next_due"])}<br><small>{_cell(m.get("due_method"))}</small></td>'
        f'<td class="marks">{html.escape(last[m["last_run_id"]])}</td></tr>' for m in machines)
    due_rows = "".join(
        f'<tr class="due-row {"overdue" if d["status"].startswith("overdue") else "soon"}"><td>{_cell(d["next_due"])}</td>'
        f'<td>{_cell(d["status"])}</td><td>{_cell(d["site"] or None)}</td>'
        f'<td><a href="?serial={html.escape(quote(d["serial_number"]))}">{_cell(d["serial_number"])}</a></td>'
        f'<td>{_cell(d["axis"])}</td><td>{_cell(d["customer"])}</td><td>{_cell(d["due_method"])}: {_cell(d["due_data"])}</td></tr>'
        for d in soon)
    body = (f"<h1>Calibration catalogue</h1><p>{html.escape(name)}: {len(machines)} machine "
            f"{'axis' if len(machines) == 1 else 'axes'}</p>"
            '<form method="get"><input name="q" placeholder="serial number, customer or instrument" size="40" '
            f'value="{html.escape(query or "")}"> <button>Search</button></form>')
    if found is not None:
        body += found
    body += (f"<h2>Overdue and due within {within:g} days</h2>"
             + (f'<table id="due"><tr><th>due</th><th>status</th><th>site</th><th>serial number</th><th>axis</th>'
                f"<th>customer</th><th>method and data</th></tr>{due_rows}</table>" if soon else
                '<p id="due">nothing overdue or due soon</p>'))
    body += ("<h2>Fleet</h2><table id=\"fleet\"><tr><th>serial number</th><th>axis</th><th>machine</th><th>customer</th>"
             "<th>site</th><th>calibrations</th><th>last</th><th>certificate</th><th>verdict</th><th>E ± U (″)</th>"
             f"<th>next due</th><th>marks</th></tr>{rows}</table>")
    if serial:
        replaced = {r["supersedes"]: r["certificate_number"] for r in history if r.get("supersedes")}
        hist = "".join(f'<tr class="run"><td>{_cell(r["measured_utc"][:19])}</td><td>{_cell(r["axis"])}</td>'
                       f'<td>{_cell(r.get("test") or r["method"])}</td><td>{html.escape(e_text(r))}</td>'
                       f'<td class="{html.escape(r["verdict"])}">{_cell(r["verdict"])}</td>'
                       f'<td>{_cell({"as_found": "as found", "as_left": "as left"}.get(r.get("state", "")))}</td>'
                       f'<td>{_cell(r["certificate_number"])}'
                       + (f' <small>(superseded by {html.escape(replaced[r["run_id"]])})</small>' if r["run_id"] in replaced else "")
                       + (f' <small>(replaces {html.escape(r["replaces"])})</small>' if r.get("replaces") else "")
                       + f'</td><td class="marks">{html.escape(marks(r))}</td></tr>' for r in history)
        trends = "".join(f"<li>axis {html.escape(a)}: " + (
            "E's trend needs two runs at different times (as-left runs apart)" if t["E_trend_arcsec_per_year"] is None
            else f"E's trend {_cell(t['E_trend_arcsec_per_year'])} ± {_cell(t['E_trend_U_arcsec_per_year'])} ″/year; "
                 f"its limit: {_cell(t['E_reaches_limit'])}") + "</li>"
            + f"<li>axis {html.escape(a)}: next due {_cell(d['due'])} — {_cell(d['method'])}: {_cell(d['data'])}</li>"
            for a, rs in sorted(by_axis(history).items()) for t, d in [(trend(rs), due(rs[0]["serial_number"], a, rs))])
        body += (f'<h2>History of {html.escape(serial)}</h2><table id="history"><tr><th>measured (UTC)</th><th>axis</th>'
                 f"<th>test</th><th>E ± U (″)</th><th>verdict</th><th>state</th><th>certificate</th><th>marks</th></tr>{hist}</table>"
                 f"<ul>{trends}</ul>")
    return f"<!doctype html><html><head><meta charset=utf-8><title>rtcal catalogue</title><style>{STYLE}</style>" \
           f"</head><body>{body}</body></html>"


def _search(cat: Catalog, machines: list[dict[str, Any]], query: str) -> str:
    """The machine axes whose serial number or customer holds ``query``, and the calibrations that used an
    instrument whose id holds it (case-insensitive)."""
    q = normal_text(query).casefold()
    hits = [m for m in machines if q in m["serial_number"].casefold() or q in m["customer"].casefold()]
    used = [r for i in cat.instrument_ids(normal_text(query), limit=20) for r in cat.used_by(i)]
    out = "".join(f'<li class="hit"><a href="?serial={html.escape(quote(m["serial_number"]))}">'
                  f'{_cell(m["serial_number"])}</a> axis {_cell(m["axis"])}: {_cell(m["customer"])}</li>' for m in hits)
    out += "".join(f'<li class="hit">{_cell(r["instrument_id"])} ({_cell(r["role"])}) used by {_cell(r["certificate_number"])} '
                   f'({_cell(r["measured_utc"][:10])}), <a href="?serial={html.escape(quote(r["serial_number"]))}">'
                   f'{_cell(r["serial_number"])}</a> axis {_cell(r["axis"])}</li>' for r in used)
    return (f'<h2>Search: {html.escape(query)}</h2><ul id="search">{out}</ul>' if out else
            f'<h2>Search: {html.escape(query)}</h2><p id="search">nothing matches</p>')


def app(location: str | None, host: str) -> Starlette:
    import anyio

    async def index(request: Request) -> HTMLResponse:
        serial = request.query_params.get("serial")
        query = (request.query_params.get("q") or "").strip()[:200] or None
        return HTMLResponse(await anyio.to_thread.run_sync(_page, location, serial, query))

    async def api(request: Request) -> Response:
        def read() -> list[dict[str, Any]]:
            with Catalog(location) as cat:
                entries = cat.machines()
                due = due_of(cat)
            last = {r["run_id"]: marks(r) for r in entries}
            return [{**m, "marks": last[m["last_run_id"]]} for m in fleet(entries, due)]
        machines = finite(await anyio.to_thread.run_sync(read))  # strict JSON: a NaN or infinity is null
        return Response(json.dumps(machines, allow_nan=False, ensure_ascii=False), media_type="application/json")

    return Starlette(routes=[Route("/", index), Route("/api/catalog", api)], middleware=[host_guard(host)])


def serve_catalog(location: str | None, host: str, port: int) -> int:
    """Serve the page until interrupted (exit 0); the URL on stderr."""
    with Catalog(location):  # a database that cannot be opened fails here, in one line, before listening
        pass
    warn_exposed(host, "catalogue page", "the lab's fleet, customers and serial numbers")
    sock = bind(host, port)
    server, thread = serve(app(location, host), sock, "rtcal-catalog")
    print(f"catalog view: {url_of(host, sock)}", file=sys.stderr, flush=True)
    try:
        while thread.is_alive():
            time.sleep(0.5)
    except KeyboardInterrupt:
        return 0
    finally:
        server.should_exit = True
        thread.join(5)
        sock.close()
    return 1
