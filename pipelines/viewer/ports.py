"""Can the viewer serve on host:port? Checked before any work starts (and before viser, which would
silently move on to the next free port)."""

from __future__ import annotations

import errno
import socket

from tridehaze_plugin.errors import UserError


def check_port_free(host: str, port: int) -> None:
    """Raise a UserError when ``host:port`` cannot be bound (in use, or not an address of this machine)."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise UserError(
            f"cannot serve the viewer on host {host!r} ({exc.strerror})",
            fix="pass a host name or address of this machine, e.g. 127.0.0.1",
        ) from None
    family, _, _, _, addr = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server itself will
        try:
            sock.bind(addr)
        except OSError as exc:
            if port and exc.errno == errno.EADDRINUSE:
                raise port_in_use(host, port) from None
            raise UserError(f"cannot serve the viewer on {host}:{port} ({exc.strerror})") from None


def port_in_use(host: str, port: int) -> UserError:
    return UserError(
        f"port {port} on {host} is already in use (another viewer or program)",
        fix="pass another port (td-train: --viewer.port, td-viewer: --port; 0 picks a free one)",
    )
