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

from rtcal.catalog.entry import marks
from rtcal.catalog.history import by_axis, e_text, fleet, trend
from rtcal.catalog.store import Catalog
from rtcal.live.web import bind, host_guard, serve, url_of, warn_exposed
from rtcal.results.io import finite

STYLE = ("body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}td,th{border:1px solid #bbb;"
         "padding:.3em .6em;text-align:left}.fail{color:#b00}.pass{color:#070}.undecided{color:#a60}"
         ".marks{color:#b00;font-weight:bold}")


def _cell(value: Any) -> str:
    return "–" if value is None else html.escape(str(value))


def _page(location: str | None, serial: str | None) -> str:
    with Catalog(location) as cat:
        entries = cat.machines()
        history = [r for rs in by_axis(cat.history(serial)).values() for r in rs] if serial else []
        name = cat.name
    machines = fleet(entries)
    last = {r["run_id"]: marks(r) for r in entries}  # the marks of each axis's last calibration
    rows = "".join(
        f'<tr class="machine"><td><a href="?serial={html.escape(quote(m["serial_number"]))}">{_cell(m["serial_number"])}</a></td>'
        f'<td>{_cell(m["axis"])}</td><td>{_cell(m["machine"])}</td><td>{m["calibrations"]}</td>'
        f'<td>{_cell(m["last_utc"][:10])}</td><td class="{html.escape(m["verdict"])}">{_cell(m["verdict"])}</td>'
        f'<td>{html.escape(e_text(m))}</td>'
        f'<td class="due">{_cell(m["next_due"])}</td><td class="marks">{html.escape(last[m["last_run_id"]])}</td></tr>'
        for m in machines)
    body = (f"<h1>Calibration catalogue</h1><p>{html.escape(name)}: {len(machines)} machine {'axis' if len(machines) == 1 else 'axes'}</p>"
            "<table id=\"fleet\"><tr><th>serial number</th><th>axis</th><th>machine</th><th>calibrations</th>"
            f"<th>last</th><th>verdict</th><th>E ± U (″)</th><th>next due</th><th>marks</th></tr>{rows}</table>")
    if serial:
        hist = "".join(f'<tr class="run"><td>{_cell(r["measured_utc"][:19])}</td><td>{_cell(r["axis"])}</td>'
                       f'<td>{_cell(r["method"])}</td><td>{html.escape(e_text(r))}</td>'
                       f'<td class="{html.escape(r["verdict"])}">{_cell(r["verdict"])}</td>'
                       f'<td>{_cell(r["certificate_number"])}</td><td class="marks">{html.escape(marks(r))}</td></tr>'
                       for r in history)
        trends = "".join(f"<li>axis {html.escape(a)}: " + (
            "E's trend needs two runs at different times (as-left runs apart)" if t["E_trend_arcsec_per_year"] is None
            else f"E's trend {_cell(t['E_trend_arcsec_per_year'])} ± {_cell(t['E_trend_U_arcsec_per_year'])} ″/year; "
                 f"reaches its limit: {_cell(t['E_reaches_limit'])}") + "</li>"
            for a, rs in sorted(by_axis(history).items()) for t in [trend(rs)])
        body += (f'<h2>History of {html.escape(serial)}</h2><table id="history"><tr><th>measured (UTC)</th><th>axis</th>'
                 f"<th>method</th><th>E ± U (″)</th><th>verdict</th><th>certificate</th><th>marks</th></tr>{hist}</table>"
                 f"<ul>{trends}</ul>")
    return f"<!doctype html><html><head><meta charset=utf-8><title>rtcal catalogue</title><style>{STYLE}</style>" \
           f"</head><body>{body}</body></html>"


def app(location: str | None, host: str) -> Starlette:
    import anyio

    async def index(request: Request) -> HTMLResponse:
        serial = request.query_params.get("serial")
        return HTMLResponse(await anyio.to_thread.run_sync(_page, location, serial))

    async def api(request: Request) -> Response:
        def read() -> list[dict[str, Any]]:
            with Catalog(location) as cat:
                entries = cat.machines()
            last = {r["run_id"]: marks(r) for r in entries}
            return [{**m, "marks": last[m["last_run_id"]]} for m in fleet(entries)]
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
