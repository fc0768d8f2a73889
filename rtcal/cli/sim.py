"""``rtcal sim serve``: every instrument over its real protocol around one simulated bench."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from rtcal.cli.common import EXIT_FAILED, EXIT_OK, UserError, one_line, seed
from simulators.servers.serve_options import (DEFAULT_STAGE, ENVIRONMENT_MODELS, MODBUS_TRANSPORTS, SERIAL_TRANSPORTS,
                                              STAGES)

OLD_MODBUS_STAGE = "modbus"  # before --stage named the product: `--stage modbus [--stage-model M]`


def stage_of(args: argparse.Namespace) -> str:
    """The one stage `--stage` names; the old `--stage modbus` and `--stage-model M` still work,
    each with a line on stderr saying what to write instead."""
    given, model = args.stage, args.stage_model
    if given == OLD_MODBUS_STAGE:
        print(f"rtcal: warning: --stage {OLD_MODBUS_STAGE} is deprecated: give --stage {model or DEFAULT_STAGE}",
              file=sys.stderr)
        given = None
    if model is not None:
        if given == "linuxcnc":
            if model != DEFAULT_STAGE:
                raise UserError("--stage-model: the stage is LinuxCNC (--stage linuxcnc); give one or the other")
        elif given is not None and given != model:
            raise UserError(f"--stage {given} and --stage-model {model}: give --stage alone (--stage-model is deprecated)")
        else:
            print(f"rtcal: warning: --stage-model is deprecated: give --stage {model}", file=sys.stderr)
            given = model
    return given or DEFAULT_STAGE


def cmd_sim_serve(args: argparse.Namespace) -> int:
    import signal
    import threading

    from simulators.scenario_file import load_scenario
    from simulators.scenario import Scenario
    from simulators.servers.hub import SimulatorHub

    scenario = load_scenario(args.scenario) if args.scenario else Scenario()
    if args.host not in ("127.0.0.1", "localhost", "::1"):
        print(f"rtcal: warning: serving on {args.host}, not only on this machine", file=sys.stderr)
    if not 0.1 <= args.ipp_idle_timeout_s <= 86400:
        raise UserError(f"--ipp-idle-timeout-s {args.ipp_idle_timeout_s:g}: must lie in 0.1 … 86400 s")
    stage = stage_of(args)
    if stage == "linuxcnc":
        _check_linuxcnc_serve(args, scenario)
    elif args.comp:
        raise UserError("--comp: a table for LinuxCNC; give --stage linuxcnc (the simulated controller takes its table "
                        "in the scenario's stage.compensation)")
    if args.machine == "linuxcnc":
        _check_linuxcnc_machine(args, scenario, stage)
    elif args.kins:
        raise UserError("--kins: the kinematics LinuxCNC loads; give --machine linuxcnc")
    hub = SimulatorHub(scenario, seed=args.seed, host=args.host, serial=args.serial, modbus=args.modbus,
                       environment=args.environment, mount_thermometer=args.mount_thermometer,
                       ipp_idle_timeout_s=args.ipp_idle_timeout_s,
                       pace_serial=not args.no_pacing, comp=args.comp, machine=args.machine, kins=args.kins,
                       **STAGES[stage])  # type: ignore[arg-type]
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):  # before LinuxCNC starts: a signal then still shuts it down
        signal.signal(sig, lambda *_: stop.set())
    try:
        addresses = hub.start()
    except (RuntimeError, OSError) as exc:
        if "linuxcnc" in (stage, args.machine):  # the controller failed, not the user's input
            print(f"rtcal: LinuxCNC could not start: {one_line(exc)}", file=sys.stderr)
            return EXIT_FAILED
        raise UserError(f"simulators could not start: {exc}") from None
    machine = None
    if args.opcua:  # the machine's identity server: its address on stderr (not an instrument of --instruments)
        from simulators.opcua_machine import OpcUaMachine, default_machines

        machine = OpcUaMachine(host=args.host, machines=default_machines())  # laid out as OPC 40001-1: two machines
        print(f"rtcal: machine identity (OPC UA): {machine.address}", file=sys.stderr, flush=True)
    if not stop.is_set():
        print(json.dumps(addresses), flush=True)
    stop.wait()
    if machine is not None:
        machine.close()
    hub.stop()
    return EXIT_OK


def _check_linuxcnc_serve(args: argparse.Namespace, scenario: Any) -> None:
    """`sim serve --stage linuxcnc`: LinuxCNC installed, a table it would read whole, no second table."""
    from rtcal.deliverables.compensation import CompensationError, parse_linuxcnc
    from simulators.servers.linuxcnc import available

    why = available()
    if why:
        raise UserError(f"--stage linuxcnc: {why}")
    if scenario.stage.compensation is not None:
        raise UserError("--stage linuxcnc: the scenario loads a table into the simulated controller (stage.compensation); "
                        "LinuxCNC applies the table: give it with --comp and remove it from the scenario")
    if args.comp:
        try:
            parse_linuxcnc(Path(args.comp).read_text(), args.comp)
        except OSError as exc:
            raise UserError(f"--comp {args.comp}: cannot read: {exc.strerror or exc}") from None
        except (CompensationError, UnicodeDecodeError) as exc:
            raise UserError(f"--comp {args.comp}: not a LinuxCNC table (COMP_FILE_TYPE 0): {one_line(exc)}") from None


def _check_linuxcnc_machine(args: argparse.Namespace, scenario: Any, stage: str) -> None:
    """`sim serve --machine linuxcnc`: LinuxCNC installed, one LinuxCNC, a scenario with a machine whose nest
    zero point is the controlled point, a --kins file LinuxCNC would read as rtcal does."""
    from simulators.servers.linuxcnc import available, kins_hal

    why = available()
    if why:
        raise UserError(f"--machine linuxcnc: {why}")
    if stage == "linuxcnc":
        raise UserError("--machine linuxcnc with --stage linuxcnc: one LinuxCNC runs on a machine; give one of them")
    machine = scenario.machine
    if machine is None:
        raise UserError(f"--machine linuxcnc: the scenario {args.scenario or '(none)'} has no `machine:` (a five-axis "
                        "machine with a trunnion table) for LinuxCNC to drive")
    if any(machine.nest.offset_mm):
        raise UserError("--machine linuxcnc: the scenario's machine.nest.offset_mm must be 0 0 0: LinuxCNC's kinematics "
                        "put the controlled point, which is the nest's zero point here (no tool offset is loaded)")
    if args.kins:
        try:
            kins_hal(machine, args.kins)
        except OSError as exc:
            raise UserError(f"--kins {args.kins}: cannot read: {exc.strerror or exc}") from None
        except (ValueError, UnicodeDecodeError) as exc:
            raise UserError(f"--kins {args.kins}: not xyzac-trt-kins pins LinuxCNC would load: {one_line(exc)}") from None


def add_sim(sub: Any) -> None:
    sim = sub.add_parser("sim", help="simulated instruments")
    sim_sub = sim.add_subparsers(dest="sim_command", required=True)
    serve = sim_sub.add_parser("serve", help="serve every instrument over its real protocol around one simulated bench; "
                                             "prints one JSON line of addresses, then serves until interrupted")
    serve.add_argument("--scenario", help="bench scenario YAML (default: an ideal bench)")
    serve.add_argument("--seed", type=seed, help="seed (default: the scenario's)")
    serve.add_argument("--host", default="127.0.0.1", help="address to bind (default: loopback only)")
    serve.add_argument("--serial", choices=SERIAL_TRANSPORTS, default="pty",
                       help="serial instruments on pseudo-terminals (default) or TCP sockets (socket:// addresses)")
    serve.add_argument("--modbus", choices=MODBUS_TRANSPORTS, default="tcp", help="stage drive over Modbus TCP or RTU")
    serve.add_argument("--stage", choices=(*STAGES, OLD_MODBUS_STAGE), metavar="{" + ",".join(STAGES) + "}",
                       help=f"the stage: an Oriental AZ drive over Modbus ({DEFAULT_STAGE}, the default), a PI controller "
                            "(GCS on a serial line), or a real LinuxCNC started headless (linuxcnc-uspace installed) whose "
                            "compensated motor position the bench's table follows")
    serve.add_argument("--stage-model", choices=[s for s in STAGES if STAGES[s]["stage"] == OLD_MODBUS_STAGE],
                       help=argparse.SUPPRESS)  # deprecated: --stage names the product
    serve.add_argument("--no-pacing", action="store_true",
                       help="serial replies at once instead of at each product's baud rate (faster tests)")
    serve.add_argument("--environment", choices=ENVIRONMENT_MODELS, default=ENVIRONMENT_MODELS[0],
                       help="the environment sensor's model (with an OMEGA iTHX thermometer on its thermometer=)")
    serve.add_argument("--mount-thermometer", action="store_true",
                       help="also serve a second iTHX, its probe 2 on the tracer's mount (the bench's mount region), and "
                            "give its address as the environment's mount_thermometer= (a procedure that states "
                            "uncertainty.environment.mount_temperature_k)")
    serve.add_argument("--ipp-idle-timeout-s", type=float, default=600.0,
                       help="release an I++ session whose client sends nothing for this long, and close its connection "
                            "(default 600 s; docs/faults.md)")
    serve.add_argument("--comp", help="with --stage linuxcnc: a LinuxCNC compensation table (what `rtcal compensate "
                                      "--format linuxcnc` writes) loaded as the joint's COMP_FILE")
    serve.add_argument("--machine", choices=("sim", "linuxcnc"), default="sim",
                       help="the scenario's machine tool: its protocol-less simulation (sim, the default: no address), "
                            "or a real LinuxCNC with xyzac-trt-kins started headless (linuxcnc-uspace installed) whose "
                            "joints the simulated machine follows (address machine_tool)")
    serve.add_argument("--kins", help="with --machine linuxcnc: the xyzac-trt-kins pins LinuxCNC loads at start (a .hal "
                                      "file of setp lines, what `rtcal compensate --format linuxcnc-xyzac-trt` writes; "
                                      "default: the scenario's nominal kinematics)")
    serve.add_argument("--opcua", action="store_true",
                       help="also serve the simulated machine's OPC 40001-1 identification over OPC UA (its opc.tcp:// "
                            "address on stderr; `rtcal probe machine` reads it, metadata.machine_identity uses it)")
    serve.set_defaults(func=cmd_sim_serve)
