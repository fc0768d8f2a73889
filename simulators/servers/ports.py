"""A free TCP port for a simulator server. Its own module so that the hub and the LinuxCNC it
starts (:mod:`simulators.servers.linuxcnc`) both use it without importing each other."""

from __future__ import annotations

import socket


def free_port(host: str) -> int:
    """A port free on ``host`` now: bound by the OS and released, for a server that needs its port
    before it listens."""
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]
