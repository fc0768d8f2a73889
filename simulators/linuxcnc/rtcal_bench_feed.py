"""rtcal's user-space HAL component: motor commands, streamed to the simulated bench.

Run by LinuxCNC's HAL file with the system Python, the only one that can import LinuxCNC's
``hal`` module. Two forms:

- ``loadusr -Wn rtcal-bench /usr/bin/python3 rtcal_bench_feed.py`` (a rotary table): pins
  (HAL_IN, degrees) ``rtcal-bench.motor-pos-cmd`` (the compensated motor position, wired to
  ``joint.N.motor-pos-cmd``) and ``rtcal-bench.pos-cmd`` (the commanded joint position,
  uncompensated); lines ``<motor_deg> <pos_cmd_deg>``.
- ``… rtcal_bench_feed.py joints N`` (a machine tool): pins ``rtcal-bench.joint-0`` …
  ``joint-<N-1>`` (HAL_IN, each joint's motor command, mm or degrees); lines of the time the pins
  were read (``time.monotonic()``, CLOCK_MONOTONIC: the hub's clock too) and the N numbers, sent
  also when nothing changed, every ``HEARTBEAT_S``, so the hub knows how recent its machine is
  (simulators/servers/joints_feed.py).

Every ``POLL_S`` it sends a line to the bench at ``$RTCAL_BENCH_FEED`` (HOST:PORT) when a pin
changed; it knows wires only: the bench turns the motor positions into where the table is. It exits when LinuxCNC unloads it (SIGTERM); when the
bench goes away (its connection closes: `rtcal sim serve` was killed, even with SIGKILL) it
sends SIGTERM to LinuxCNC's process group, whose ``linuxcnc`` script then shuts LinuxCNC down,
so no controller outlives its simulated bench.
"""

import os
import select
import signal
import socket
import sys
import time

import hal

POLL_S = 0.002  # 500 Hz: a reversal of motion lasts far longer, so the bench sees every direction
MAX_PASSES = 100
HEARTBEAT_S = 0.01


def snapshot(comp, pins):
    """The pins as one servo period left them: read until two passes agree. The servo thread writes them
    while this process reads them one by one, so one pass can mix two periods (seen on a loaded host: the
    X joint of one period with the C joint of a later one, the machine 1 mm off its path)."""
    now = tuple(comp[pin] for pin in pins)
    for _ in range(MAX_PASSES):
        again = tuple(comp[pin] for pin in pins)
        if again == now:
            break
        now = again
    return now


def main() -> int:
    comp = hal.component("rtcal-bench")
    stamped = sys.argv[1:2] == ["joints"]
    if stamped:
        pins = [f"joint-{i}" for i in range(int(sys.argv[2]))]
    else:
        pins = ["motor-pos-cmd", "pos-cmd"]
    for pin in pins:
        comp.newpin(pin, hal.HAL_FLOAT, hal.HAL_IN)
    where = os.environ.get("RTCAL_BENCH_FEED", "")
    sock = None
    if where:
        host, _, port = where.rpartition(":")
        sock = socket.create_connection((host, int(port)), timeout=5)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    comp.ready()
    last = None
    sent_s = 0.0
    bench_gone = False
    try:
        while not stop:
            read_s = time.monotonic()
            now = snapshot(comp, pins)
            if sock is not None and (now != last or (stamped and read_s - sent_s >= HEARTBEAT_S)):
                sock.sendall((" ".join(repr(v) for v in ((read_s,) if stamped else ()) + now) + "\n").encode())
                last, sent_s = now, read_s
            if sock is None:
                time.sleep(POLL_S)
            elif select.select([sock], [], [], POLL_S)[0] and not sock.recv(64):
                raise OSError("the bench closed its end")
    except OSError:
        bench_gone = True
    except KeyboardInterrupt:
        pass
    finally:
        comp.exit()
    if bench_gone and not stop:
        os.killpg(os.getpgrp(), signal.SIGTERM)
    return 0


if __name__ == "__main__":
    sys.exit(main())
