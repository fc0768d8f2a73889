"""The ``rtcal`` command line. User mistakes exit 2 with a located message, never a traceback."""

from __future__ import annotations

import argparse
import csv
import json
import os
import sys
from pathlib import Path

import numpy as np

from drivers.addresses import AddressError
from drivers.errors import InstrumentError
from rtcal import __version__
from rtcal.yamlfile import FileProblems

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2
EXIT_INTERRUPTED = 130
MAX_SEED = 2**63 - 1


class UserError(Exception):
    """A mistake the user can fix; printed as one line, exit code 2."""


def _interrupt(*_) -> None:
    raise KeyboardInterrupt


def _how_to_go_on(run_dir: str) -> str:
    if (Path(run_dir) / "run.sqlite").is_file():
        return f"every reading taken so far is in {run_dir}/run.sqlite; `rtcal resume {run_dir}` goes on"
    return "nothing was measured"


def _execute(start, run_dir: str) -> int:
    """Run or resume; print the outcome, or what went wrong and how to go on."""
    import signal

    from rtcal.methods.abbe import CertificateUnavailable
    from rtcal.rundir import RunDirError
    from rtcal.runner import METHODS, AnalysisFailed

    signal.signal(signal.SIGTERM, _interrupt)  # `kill` stops like Ctrl-C: status recorded, run directory released
    try:
        outcome = start()
    except (FileExistsError, CertificateUnavailable, RunDirError) as exc:
        raise UserError(str(exc)) from None
    except AnalysisFailed as exc:
        print(f"rtcal: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except InstrumentError as exc:
        print(f"rtcal: instrument error: {exc}", file=sys.stderr)
        print(f"rtcal: {_how_to_go_on(run_dir)}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        print(f"\nrtcal: interrupted; {_how_to_go_on(run_dir)}", file=sys.stderr)
        return EXIT_INTERRUPTED
    print(f"run complete: {outcome.results['raw_readings']} readings stored")
    for line in METHODS[outcome.results["method"]].summary(outcome.results):
        print(line)
    files = ", ".join(sorted(p.name for p in outcome.run_dir.iterdir() if not p.name.startswith((".", "run.sqlite-"))))
    print(f"results in {outcome.run_dir}/ ({files})")
    return EXIT_OK


def _cmd_run(args: argparse.Namespace) -> int:
    from rtcal.runner import default_run_dir, run_procedure

    addresses = parse_instruments_option(args.instruments) if args.instruments else None
    out = args.out or str(default_run_dir(Path(args.procedure).stem))
    return _execute(lambda: run_procedure(args.procedure, args.scenario, args.seed, out, addresses=addresses,
                                          virtual_clock=args.virtual_clock, large=args.large), out)


def _cmd_resume(args: argparse.Namespace) -> int:
    from rtcal.runner import resume_run

    addresses = parse_instruments_option(args.instruments) if args.instruments else None
    return _execute(lambda: resume_run(args.run_dir, addresses=addresses, virtual_clock=args.virtual_clock), args.run_dir)


def parse_instruments_option(text: str) -> dict[str, str]:
    """``--instruments``: a JSON object of name → address, inline or in a file."""
    from rtcal.yamlfile import read_text

    source = text
    if not text.lstrip().startswith("{"):
        try:
            source = read_text(text)
        except FileProblems as exc:
            raise UserError(f"--instruments: {exc.problems[0].file}: {exc.problems[0].message}") from None
    try:
        data = json.loads(source.strip().splitlines()[0] if source.strip() else "")
    except (json.JSONDecodeError, IndexError) as exc:
        raise UserError(f"--instruments: not a JSON object of instrument addresses ({exc})") from None
    if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
        raise UserError("--instruments: expected a JSON object mapping instrument names to address strings")
    return data


def _cmd_sim_serve(args: argparse.Namespace) -> int:
    import signal
    import threading

    from rtcal.procedure.loader import load_scenario
    from simulators.scenario import Scenario
    from simulators.servers.hub import SimulatorHub

    scenario = load_scenario(args.scenario) if args.scenario else Scenario()
    if args.host not in ("127.0.0.1", "localhost", "::1"):
        print(f"rtcal: warning: serving on {args.host}, not only on this machine", file=sys.stderr)
    hub = SimulatorHub(scenario, seed=args.seed, host=args.host, serial=args.serial, modbus=args.modbus)
    try:
        addresses = hub.start()
    except (RuntimeError, OSError) as exc:
        raise UserError(f"simulators could not start: {exc}") from None
    print(json.dumps(addresses), flush=True)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    stop.wait()
    hub.stop()
    return EXIT_OK


def _cmd_validate(args: argparse.Namespace) -> int:
    from rtcal.procedure.loader import bench_path, is_procedure_text, load_procedure, load_scenario
    from rtcal.yamlfile import read_text

    problems = []
    for name in args.files:
        path = Path(name)
        try:
            text = read_text(path)
            if is_procedure_text(text):
                proc = load_procedure(path, args.large, text)
                if proc.bench is not None:
                    load_scenario(bench_path(path, proc))
            else:
                load_scenario(path)
            print(f"{path}: ok")
        except FileProblems as exc:
            problems += [str(p) for p in exc.problems]
    for p in problems:
        print(p, file=sys.stderr)
    return EXIT_USAGE if problems else EXIT_OK


def _cmd_schema(args: argparse.Namespace) -> int:
    from rtcal.procedure.loader import procedure_schema, scenario_schema

    print(scenario_schema() if args.scenario else procedure_schema())
    return EXIT_OK


def read_stations_csv(path: Path) -> np.ndarray:
    """Station centres from a CSV with header X,Y,Z (mm), one station per row, in order."""
    import io

    from rtcal.yamlfile import read_bytes

    try:
        data = read_bytes(path, 16 * 1024 * 1024)
    except FileProblems as exc:
        raise UserError(str(exc.problems[0])) from None
    try:
        with io.StringIO(data.decode("utf-8"), newline="") as fh:
            reader = csv.DictReader(fh)
            fields = [f.strip() for f in (reader.fieldnames or [])]
            if not {"X", "Y", "Z"} <= set(fields):
                raise UserError(f"{path}:1: header must name X,Y,Z (found {','.join(fields) or 'nothing'})")
            rows = []
            for k, row in enumerate(reader, start=2):
                row = {key.strip(): v for key, v in row.items() if key}
                try:
                    xyz = [float(row["X"]), float(row["Y"]), float(row["Z"])]
                except (TypeError, ValueError):
                    raise UserError(f"{path}:{k}: X, Y and Z must be numbers (mm)") from None
                if not all(abs(v) <= 1e6 for v in xyz):  # also false for NaN
                    raise UserError(f"{path}:{k}: X, Y and Z must be finite and within ±1e6 mm")
                rows.append(xyz)
    except UnicodeDecodeError:
        raise UserError(f"{path}: not UTF-8 text") from None
    except csv.Error as exc:
        raise UserError(f"{path}:{reader.line_num}: not CSV: {exc}") from None
    if len(rows) < 4:
        raise UserError(f"{path}: {len(rows)} stations; at least 4 are needed (eq. 2)")
    return np.array(rows)


def _cmd_solve_stations(args: argparse.Namespace) -> int:
    from rtcal.solvers.paper000 import PAPER_NOTES, chain_from_stations

    stations = read_stations_csv(Path(args.file))
    if not 0 < args.step_deg < 180:
        raise UserError("--step-deg must lie in (0, 180)")
    if not abs(args.first_deg) <= 36000:
        raise UserError("--first-deg must be finite and within ±36000")
    nominal = np.deg2rad(args.first_deg + args.step_deg * np.arange(len(stations)))
    try:
        chain = chain_from_stations(stations, nominal)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise UserError(f"{args.file}: stations do not define a plane and a circle: {exc}") from None
    out = {
        "plane": {"a": chain.plane.a, "b": chain.plane.b, "c": chain.plane.c, "e": chain.plane.e},
        "projected_stations_mm": np.round(chain.projected_mm, 6).tolist(),
        "center_mm": np.round(chain.center_mm, 6).tolist(),
        "deviation_arcsec": np.round(chain.deviation_arcsec, 4).tolist(),
        "sigma_arcsec": round(chain.sigma_arcsec, 4),
        "algorithm_error_arcsec": chain.algorithm_error_arcsec,
        "notes": list(PAPER_NOTES),
    }
    print(json.dumps(out, indent=2))
    return EXIT_OK


def _seed(text: str) -> int:
    """``--seed``: a whole number 0 … 2⁶³ − 1 (numpy's generators take no negative seeds)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if not 0 <= value <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"{text} is outside 0 … {MAX_SEED}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rtcal", description="Angular positioning calibration of rotary tables.")
    parser.add_argument("--version", action="version", version=f"rtcal {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run a procedure and write a run directory")
    run.add_argument("procedure", help="procedure YAML file")
    run.add_argument("--scenario", help="bench scenario YAML (replaces the procedure's `bench`)")
    run.add_argument("--seed", type=_seed, help="seed of the run's random generator (default: the scenario's)")
    run.add_argument("--out", help="run directory (default: runs/<time>-<procedure>)")
    run.add_argument("--instruments", help="JSON object (or file) of instrument addresses, e.g. what `rtcal sim serve` "
                                           "prints; replaces the procedure's instrument section")
    run.add_argument("--virtual-clock", action="store_true",
                     help="do not wait settle times in real time (for protocol simulators, never for hardware)")
    run.add_argument("--large", action="store_true",
                     help="accept a plan beyond 100 000 readings (up to 2 000 000; takes hours and GBs)")
    run.set_defaults(func=_cmd_run)

    resume = sub.add_parser("resume", help="continue an interrupted run: every planned reading not yet stored, once")
    resume.add_argument("run_dir")
    resume.add_argument("--instruments", help="new instrument addresses (JSON object or file), e.g. of a restarted simulator")
    resume.add_argument("--virtual-clock", action="store_true", help="as for `run`")
    resume.set_defaults(func=_cmd_resume)

    sim = sub.add_parser("sim", help="simulated instruments")
    sim_sub = sim.add_subparsers(dest="sim_command", required=True)
    serve = sim_sub.add_parser("serve", help="serve every instrument over its real protocol around one simulated bench; "
                                             "prints one JSON line of addresses, then serves until interrupted")
    serve.add_argument("--scenario", help="bench scenario YAML (default: an ideal bench)")
    serve.add_argument("--seed", type=_seed, help="seed (default: the scenario's)")
    serve.add_argument("--host", default="127.0.0.1", help="address to bind (default: loopback only)")
    serve.add_argument("--serial", choices=["pty", "tcp"], default="pty",
                       help="serial instruments on pseudo-terminals (default) or TCP sockets (socket:// addresses)")
    serve.add_argument("--modbus", choices=["tcp", "rtu"], default="tcp", help="stage drive over Modbus TCP or RTU")
    serve.set_defaults(func=_cmd_sim_serve)

    val = sub.add_parser("validate", help="check procedure or scenario files; problems as file:line:column")
    val.add_argument("files", nargs="+")
    val.add_argument("--large", action="store_true", help="as for `run`: accept plans beyond the default size limits")
    val.set_defaults(func=_cmd_validate)

    schema = sub.add_parser("schema", help="print the JSON Schema of procedure files")
    schema.add_argument("--scenario", action="store_true", help="print the scenario schema instead")
    schema.set_defaults(func=_cmd_schema)

    solve = sub.add_parser("solve", help="run a solver on data files")
    solve_sub = solve.add_subparsers(dest="solver", required=True)
    st = solve_sub.add_parser("stations", help="plane, circle and deviations from station centres (CSV X,Y,Z)")
    st.add_argument("file")
    st.add_argument("--step-deg", type=float, required=True, help="nominal angle between adjacent stations")
    st.add_argument("--first-deg", type=float, default=0.0, help="nominal angle of the first station")
    st.set_defaults(func=_cmd_solve_stations)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except FileProblems as exc:
        for p in exc.problems:
            print(p, file=sys.stderr)
        return EXIT_USAGE
    except (UserError, AddressError) as exc:
        print(f"rtcal: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except InstrumentError as exc:
        print(f"rtcal: instrument error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except BrokenPipeError:  # the reader of our output went away (| head): not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    except KeyboardInterrupt:
        print("rtcal: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
