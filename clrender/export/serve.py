"""A tiny threaded HTTP server for an exported folder on 127.0.0.1 (a file:// page cannot
fetch its binary assets)."""
from __future__ import annotations

import errno
import functools
import threading
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path


# The port of clrender's local servers (`clrender view`, `clrender export --serve`).
DEFAULT_PORT = 8080


class _Quiet(SimpleHTTPRequestHandler):
    def log_message(self, *args):     # no line per request on stderr
        pass


def serve(folder, host: str = "127.0.0.1", port: int = 0, block: bool = False):
    """Serve ``folder`` (port 0: a free one). Returns ``(url, server)``; the server runs in
    a daemon thread (``server.shutdown()`` stops it), or in this thread when ``block``."""
    folder = Path(folder)
    if not (folder / "index.html").is_file():
        raise FileNotFoundError(f"{folder}: no index.html (not an exported page)")
    handler = functools.partial(_Quiet, directory=str(folder))
    try:
        server = ThreadingHTTPServer((host, port), handler)
    except OSError as exc:
        if exc.errno != errno.EADDRINUSE:
            raise
        raise ValueError(f"port {port} on {host} is in use: choose another (--port N, or "
                         "--port 0 for a free one)") from None
    url = f"http://{host}:{server.server_address[1]}/"
    if block:
        print(f"serving {folder} at {url} (Ctrl-C stops)")
        try:
            server.serve_forever()
        except KeyboardInterrupt:
            pass
        finally:
            server.server_close()
    else:
        threading.Thread(target=server.serve_forever, daemon=True).start()
    return url, server
