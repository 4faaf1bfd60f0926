"""The viewer's server (viser: a web server on this machine that any browser opens, the
3D drawing done in the browser, so no OpenGL is needed here) and its static export: one
self-contained HTML file with the scene and viser's client inlined, which opens offline,
titled and with its legend.

viser is an optional extra (`pip install -e '.[view]'`): it is imported here, when a view
starts, and its absence is a one-line error."""

from __future__ import annotations

import contextlib
import os
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from lmjx.errors import ConfigError, LmjxError
from lmjx.runtime.fileio import atomic_path, check_writable
from lmjx.view.legend import Page, with_page

INSTALL_HINT = "lmjx view needs viser: pip install -e '.[view]'"


class ViewerMissingError(LmjxError):
    """viser, the viewer's library, is not installed."""


def require_viser() -> Any:
    """The viser module, or ViewerMissingError in one line with the command that installs it."""
    try:
        import viser
    except ImportError:
        raise ViewerMissingError(INSTALL_HINT) from None
    return viser


def check_port(host: str, port: int) -> None:
    """Refuse a port out of range or one something else listens on (viser would quietly
    take the next free one, and the address a user tunnels to would show nothing)."""
    if not 0 <= port <= 65535:
        raise ConfigError(f"--port {port} is out of range; give 1 to 65535 (0: any free port)")
    if port == 0:
        return
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, port))
        except OSError as e:
            raise ConfigError(f"port {port} on {host} is in use ({e.strerror}); choose another with --port") from None


def start_server(host: str, port: int, label: str) -> Any:
    """A viser server on host:port (port 0: any free port), or a one-line error."""
    viser = require_viser()
    check_port(host, port)
    try:
        with open(os.devnull, "w") as quiet, contextlib.redirect_stdout(quiet):  # viser's banner: lmjx says its own
            server = viser.ViserServer(host=host, port=port, label=label, verbose=False)
    except OSError as e:
        raise ConfigError(f"cannot serve on {host}:{port} ({e.strerror}); choose another --port or --host") from None
    if port and server.get_port() != port:  # taken between the check and the start
        stop_server(server)
        raise ConfigError(f"port {port} on {host} is in use; choose another with --port")
    return server


def stop_server(server: Any) -> None:
    with open(os.devnull, "w") as quiet, contextlib.redirect_stdout(quiet):  # viser says it stopped
        server.stop()


def url_of(server: Any) -> str:
    host = server.get_host()
    shown = "localhost" if host in ("127.0.0.1", "0.0.0.0", "::1", "::") else host
    return f"http://{shown}:{server.get_port()}"


def write_html(serializer: Any, out: str | Path, page: Page | None = None) -> int:
    """The scene a serializer recorded, as one self-contained HTML file (viser's static
    export: the scene zstd-compressed and base64-encoded beside viser's client, both inline),
    with the page's title and legend (`lmjx.view.legend`), written atomically; returns its
    size in bytes."""
    html = serializer.as_html()
    if page is not None:
        html = with_page(html, page)
    with atomic_path(out) as tmp:
        Path(tmp).write_text(html, encoding="utf-8")
    return len(html.encode("utf-8"))


def check_html_path(out: str | Path) -> None:
    if Path(out).suffix.lower() not in (".html", ".htm"):
        raise ConfigError(f"--html {out}: the export is an HTML file; give a name ending in .html")
    check_writable(out, "HTML export")


def serve_until_interrupted(server: Any, tick: Callable[[], None] | None = None, period: float = 0.05) -> None:
    """Keep serving (calling `tick` every `period` seconds: animations) until Ctrl-C."""
    while True:
        if tick is not None:
            tick()
        time.sleep(period)
