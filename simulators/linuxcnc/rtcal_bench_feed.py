"""rtcal's user-space HAL component: the rotary joint's motor command, streamed to the simulated bench.

Run by LinuxCNC's HAL file (``loadusr -Wn rtcal-bench /usr/bin/python3 rtcal_bench_feed.py``)
with the system Python, the only one that can import LinuxCNC's ``hal`` module. Pins (HAL_IN,
degrees): ``rtcal-bench.motor-pos-cmd`` (the compensated motor position, wired to
``joint.N.motor-pos-cmd``) and ``rtcal-bench.pos-cmd`` (the commanded joint position,
uncompensated). Every ``POLL_S`` it sends ``<motor_deg> <pos_cmd_deg>\\n`` to the bench at
``$RTCAL_BENCH_FEED`` (HOST:PORT) when either changed; it knows wires only: the bench turns the
motor position into where the table is. It exits when LinuxCNC unloads it (SIGTERM); when the
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


def main() -> int:
    comp = hal.component("rtcal-bench")
    comp.newpin("motor-pos-cmd", hal.HAL_FLOAT, hal.HAL_IN)
    comp.newpin("pos-cmd", hal.HAL_FLOAT, hal.HAL_IN)
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
    bench_gone = False
    try:
        while not stop:
            now = (comp["motor-pos-cmd"], comp["pos-cmd"])
            if now != last and sock is not None:
                sock.sendall(f"{now[0]!r} {now[1]!r}\n".encode())
                last = now
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
