"""The console's page over HTTP (the standard library's http.server, one thread per request).

``GET /`` the page, ``GET /map.json`` the static map, ``GET /state.json`` the mission as it is
(:meth:`console.desk.Desk.snapshot`), ``POST /action`` one action (JSON ``{"stage": j,
"action": "approve" | "veto" | "force", "carrier": id}``), answered with the coordinator's
``{"accepted", "reason", "detail"}``. Served on 127.0.0.1 by default, where the base station's
own screen needs no credential; bound to another address it must be served over TLS and every
request must carry the mission's operator credential (HTTP basic authentication, user
``operator``, the password in ``operator.token``; docs/fleet.md, "The operator console").
"""
from __future__ import annotations

import base64
import hmac
import json
import ssl
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources

from console import CONSOLE_OPERATOR
from console.desk import ANSWER_WAIT_S

#: Largest request body accepted (bytes).
MAX_BODY = 4096
LOOPBACK = ("127.0.0.1", "localhost", "::1")


class ConsoleUnavailable(RuntimeError):
    """The console's address cannot be served (the port is taken, the certificate unreadable)."""


class ConsoleServer:
    """The page's server in a daemon thread.

    Args:
        desk: the :class:`console.desk.Desk`; view: the :class:`console.view.ConsoleView`;
        settings: the :class:`console.hold.OperatorSettings` (bind address, port, TLS).

    Raises:
        ValueError: a non-loopback address without TLS.
        ConsoleUnavailable: the port is taken, or the certificate cannot be loaded.
    """

    def __init__(self, desk, view, settings):
        if settings.bind not in LOOPBACK and settings.tls is None:
            raise ValueError(f"the operator console on {settings.bind} must be served over TLS (--operator-tls)")
        self.desk, self.view, self.settings = desk, view, settings
        self.page = resources.files("console").joinpath("page.html").read_bytes()
        handler = type("Handler", (_Handler,), {"console": self})
        try:
            self.httpd = ThreadingHTTPServer((settings.bind, settings.port), handler)
        except OSError as exc:
            raise ConsoleUnavailable(f"--operator-port: cannot serve the console on {settings.bind}:{settings.port} "
                                     f"({exc.strerror})") from None
        self.httpd.daemon_threads = True
        if settings.tls is not None:
            try:
                context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
                context.load_cert_chain(*settings.tls)
            except (OSError, ssl.SSLError) as exc:
                self.httpd.server_close()
                raise ConsoleUnavailable(f"--operator-cert: cannot load {settings.tls[0]} with its key ({exc})") from None
            self.httpd.socket = context.wrap_socket(self.httpd.socket, server_side=True)
        self.credential = None if settings.tls is None else desk.token
        self.port = self.httpd.server_address[1]
        self._thread = threading.Thread(target=self.httpd.serve_forever, kwargs={"poll_interval": 0.2},
                                        daemon=True, name="operator-console")
        self._thread.start()

    @property
    def url(self) -> str:
        scheme = "https" if self.settings.tls is not None else "http"
        return f"{scheme}://{self.settings.bind}:{self.port}/"

    def close(self) -> None:
        self.httpd.shutdown()
        self.httpd.server_close()


class _Handler(BaseHTTPRequestHandler):
    console: ConsoleServer
    protocol_version = "HTTP/1.1"

    def log_message(self, *args) -> None:  # the coordinator's log says what matters
        pass

    def _authorised(self) -> bool:
        token = self.console.credential
        if token is None:
            return True
        header = self.headers.get("Authorization", "")
        if header.startswith("Basic "):
            try:
                user, _, password = base64.b64decode(header[6:]).decode().partition(":")
            except Exception:
                return False
            return user == "operator" and hmac.compare_digest(password.encode(), token.encode())
        return False

    def _send(self, code: int, body: bytes, kind: str = "application/json") -> None:
        self.send_response(code)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        if code == 401:
            self.send_header("WWW-Authenticate", 'Basic realm="marsupial operator"')
        self.end_headers()
        self.wfile.write(body)

    def _json(self, code: int, value) -> None:
        self._send(code, json.dumps(value).encode())

    def do_GET(self) -> None:
        if not self._authorised():
            return self._json(401, {"error": "the operator credential is required"})
        path = self.path.split("?", 1)[0]
        if path in ("/", "/index.html"):
            return self._send(200, self.console.page, "text/html; charset=utf-8")
        if path == "/map.json":
            return self._json(200, self.console.view.map())
        if path == "/state.json":
            return self._json(200, self.console.desk.snapshot())
        return self._json(404, {"error": f"no {path}"})

    def do_POST(self) -> None:
        if not self._authorised():
            return self._json(401, {"error": "the operator credential is required"})
        if self.path.split("?", 1)[0] != "/action":
            return self._json(404, {"error": f"no {self.path}"})
        try:
            length = int(self.headers.get("Content-Length", "0"))
            if not 0 < length <= MAX_BODY:
                raise ValueError(f"body of {length} bytes (1..{MAX_BODY})")
            body = json.loads(self.rfile.read(length))
            stage, action = int(body["stage"]), str(body["action"])
            carrier = body.get("carrier")
            carrier = None if carrier is None else str(carrier)
        except Exception as exc:
            return self._json(400, {"accepted": False, "reason": "malformed", "detail": str(exc)[:200]})
        answer = self.console.desk.submit(stage, action, carrier, CONSOLE_OPERATOR).wait(ANSWER_WAIT_S)
        return self._json(200, answer)
