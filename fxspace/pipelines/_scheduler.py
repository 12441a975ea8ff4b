"""``--scheduler``: a Dask scheduler's address checked (`check_scheduler`), probed for a
Dask greeting and connected to within a bounded time, or a `SchedulerError` saying what
is wrong (malformed, unreachable, or another protocol)."""

from __future__ import annotations

import re
import threading
from typing import Any

from fxspace.errors import FxspaceError


class SchedulerError(FxspaceError, ConnectionError):
    """``--scheduler`` is malformed, unreachable, or not a Dask scheduler (names which)."""



_ADDRESS = re.compile(
    r"^(?:(?P<scheme>[A-Za-z][A-Za-z0-9+.-]*)://)?"
    r"(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(?P<port>[0-9]+)/?$"
)
_SCHEMES = ("tcp", "tls", "ucx", "ws", "wss")


def check_scheduler(address: Any) -> tuple[str, str, int]:
    """``(scheme, host, port)`` of a ``--scheduler`` address (``tcp://HOST:PORT``,
    ``tls://…``, or ``HOST:PORT`` for tcp), or a `SchedulerError` saying what is wrong."""
    ex = "e.g. tcp://10.0.0.5:8786 (the address `dask scheduler` prints)"
    if not isinstance(address, str) or not address.strip():
        raise SchedulerError(f"--scheduler must be an address like tcp://HOST:PORT, got "
                             f"{address!r}; {ex}")  # fmt: skip
    a = address.strip()
    m = _ADDRESS.match(a)
    scheme = (m.group("scheme") if m else a.partition("://")[0] if "://" in a else "") or "tcp"
    if scheme.lower() in ("http", "https"):
        raise SchedulerError(
            f"--scheduler {a}: an http:// address is the Dask dashboard (port 8787), not the "
            f"scheduler; give tcp://HOST:PORT, {ex}"
        )
    if scheme.lower() not in _SCHEMES:
        raise SchedulerError(f"--scheduler {a}: unknown protocol {scheme!r}; one of "
                             f"{', '.join(s + '://' for s in _SCHEMES)}, {ex}")  # fmt: skip
    if m is None:
        raise SchedulerError(f"--scheduler {a}: not HOST:PORT after {scheme}://; {ex}")
    port = int(m.group("port"))
    if not 0 < port < 65536:
        raise SchedulerError(f"--scheduler {a}: port {port} is not in 1-65535; {ex}")
    return scheme.lower(), m.group("host"), port


def _probe_scheduler(address: str, host: str, port: int, timeout: float) -> None:
    """Connect to ``host:port`` within ``timeout`` s and read the greeting a Dask
    scheduler sends unasked (a length-prefixed handshake); a `SchedulerError` otherwise."""
    import socket

    h = host[1:-1] if host.startswith("[") else host
    try:
        sock = socket.create_connection((h, port), timeout=timeout)
    except socket.gaierror as e:
        raise SchedulerError(f"--scheduler {address}: unknown host {h!r} ({e.strerror}); "
                             "check the name") from None  # fmt: skip
    except ConnectionRefusedError:
        raise SchedulerError(
            f"--scheduler {address}: nothing listens on port {port} of {h} (connection "
            f"refused); start `dask scheduler --port {port}` there, or check the address"
        ) from None
    except TimeoutError:
        raise SchedulerError(f"--scheduler {address}: no answer within {timeout:g} s (the host "
                             "is down or a firewall drops the port)") from None  # fmt: skip
    except OSError as e:
        raise SchedulerError(f"--scheduler {address}: cannot connect ({e.strerror or e})") from None
    head = b""
    with sock:
        sock.settimeout(timeout)
        try:
            while len(head) < 8:
                chunk = sock.recv(64)
                if not chunk:
                    break
                head += chunk
        except (TimeoutError, OSError):
            pass
    n = int.from_bytes(head[:8], "little") if len(head) >= 8 else 0
    if not head:
        raise SchedulerError(
            f"--scheduler {address}: the port accepted the connection but sent no Dask "
            f"greeting within {timeout:g} s, so it speaks another protocol (an HTTP server? "
            "the scheduler listens on 8786 by default, its dashboard on 8787)"
        )
    if not 0 < n < 1 << 20:
        raise SchedulerError(
            f"--scheduler {address}: the port answered {head[:16]!r}, not a Dask scheduler's "
            "greeting (another service; the scheduler listens on 8786 by default)"
        )


def _connect(address: str, timeout: float) -> Any:
    """A ``dask.distributed.Client`` of the scheduler at ``address``, or a
    `SchedulerError` within about ``timeout`` s (the address checked and, for tcp,
    probed first; the handshake itself bounded too)."""
    from dask.distributed import Client

    scheme, host, port = check_scheduler(address)
    if scheme == "tcp":
        _probe_scheduler(address, host, port, timeout)
    box: dict[str, Any] = {}

    def go() -> None:
        try:
            box["client"] = Client(address, timeout=timeout)
        except BaseException as e:  # noqa: BLE001 - handed to the caller
            box["error"] = e

    t = threading.Thread(target=go, name="fxspace-scheduler-connect", daemon=True)
    t.start()
    t.join(timeout + 5.0)
    if t.is_alive():
        raise SchedulerError(f"--scheduler {address}: no Dask handshake within "
                             f"{timeout + 5:g} s; is it a Dask scheduler?")  # fmt: skip
    if "error" in box:
        e = box["error"]
        raise SchedulerError(f"--scheduler {address}: {type(e).__name__}: {e}") from e
    return box["client"]
