"""Zenoh configuration for fleet processes, following zenoh's own CLI conventions.

Order of precedence (later wins): zenoh's defaults, then the fleet's defaults (multicast
scouting off, unless the config file mentions ``multicast``; room for :data:`MAX_SESSIONS`
sessions and :data:`ACCEPT_PENDING` handshakes in progress, unless the file mentions
``max_sessions`` / ``accept_pending``; shared memory off, unless it mentions
``shared_memory``: see :data:`SHARED_MEMORY`), then ``--zenoh-config FILE.json5``,
then the ``--mode``, ``--listen`` and ``--connect`` flags, which override the file's keys.
"""
from __future__ import annotations

import json
import os
import re
import threading
from typing import Sequence

import zenoh

from planner.limits import TRANSPORT_MAX_MESSAGE_BYTES

#: Zenoh endpoint syntax accepted on the command line, e.g. ``tcp/127.0.0.1:7447``.
ENDPOINT_PATTERN = re.compile(r"^[a-z0-9]+/[^\s]+$")

#: Default port when a coordinator is started alone without --listen (zenoh's usual port).
DEFAULT_PORT = 7447
#: Unicast sessions a node accepts (zenoh's default is 1,000: fewer than a 1,024-carrier
#: mission's sessions on its coordinator or router).
MAX_SESSIONS = 10_000
#: Incoming sessions a node handshakes at once (zenoh's default 100; a large fleet's carriers
#: connect within seconds of each other).
ACCEPT_PENDING = 2_000


#: Zenoh's shared-memory transport, off by default for fleet processes. zenoh 1.x turns it on
#: with a pool per session that every large message goes through (an Observation with a long
#: trail, a large fleet's Decision), and the pool's pages stay resident, so memory grows with the
#: sessions (docs/performance.md, "Memory"). The fleet's messages are small and cross TCP anyway
#: (loopback or hosts); a config file that mentions ``shared_memory`` decides.
SHARED_MEMORY = False


class ConfigError(ValueError):
    """A bad Zenoh setting from the user: one line naming the flag or file."""


def file_sets_mode(config_file: str | None) -> bool:
    """Whether a zenoh config file sets the top-level ``mode``; then a role's default mode does
    not override it (an explicit --mode flag still does)."""
    if not config_file or not os.path.isfile(config_file):
        return False
    try:
        return json.loads(zenoh.Config.from_file(config_file).get_json("mode")) is not None
    except Exception:
        return False  # make_config reports a bad file


def file_listens(config_file: str | None) -> bool:
    """Whether a zenoh config file sets listen endpoints of its own (zenoh's defaults do not
    count): a coordinator given such a file and no --listen is the rendezvous, as with --listen."""
    if not config_file or not os.path.isfile(config_file):
        return False
    try:
        endpoints = json.loads(zenoh.Config.from_file(config_file).get_json("listen/endpoints"))
        return bool(endpoints) and endpoints != json.loads(zenoh.Config().get_json("listen/endpoints"))
    except Exception:
        return False  # make_config reports a bad file


def check_endpoint(endpoint: str, flag: str) -> str:
    if not isinstance(endpoint, str) or not ENDPOINT_PATTERN.match(endpoint):
        raise ConfigError(f"{flag}: expected an endpoint like tcp/127.0.0.1:7447, found {endpoint!r}")
    return endpoint


def make_config(
    mode: str | None = None,
    listen: Sequence[str] = (),
    connect: Sequence[str] = (),
    config_file: str | None = None,
) -> zenoh.Config:
    """Build a ``zenoh.Config``.

    Args:
        mode: ``peer``, ``client`` or ``router``; None keeps the file's (or zenoh's) mode.
        listen: endpoints to listen on (replace the file's ``listen/endpoints``).
        connect: endpoints to connect to (replace the file's ``connect/endpoints``).
        config_file: a zenoh JSON5 config file.

    Raises:
        ConfigError: with one line naming the bad flag or file.
    """
    text = ""
    if config_file:
        if not os.path.isfile(config_file):
            raise ConfigError(f"--zenoh-config: file not found: {config_file}")
        try:
            with open(config_file, encoding="utf-8") as handle:
                text = handle.read()
            conf = zenoh.Config.from_file(config_file)
        except Exception as exc:
            raise ConfigError(f"{config_file}: not a valid zenoh config: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
    else:
        conf = zenoh.Config()
    if "multicast" not in text:
        conf.insert_json5("scouting/multicast/enabled", "false")
    if "max_sessions" not in text:
        conf.insert_json5("transport/unicast/max_sessions", str(MAX_SESSIONS))
    if "accept_pending" not in text:
        conf.insert_json5("transport/unicast/accept_pending", str(ACCEPT_PENDING))
    if "max_message_size" not in text:  # a huge payload is dropped by the first hop's transport
        conf.insert_json5("transport/link/rx/max_message_size", str(TRANSPORT_MAX_MESSAGE_BYTES))
    if "shared_memory" not in text:
        conf.insert_json5("transport/shared_memory/enabled", json.dumps(SHARED_MEMORY))
    if mode is not None:
        if mode not in ("peer", "client", "router"):
            raise ConfigError(f"--mode: expected peer, client or router, found {mode!r}")
        conf.insert_json5("mode", json.dumps(mode))
    try:
        if listen:
            conf.insert_json5("listen/endpoints", json.dumps([check_endpoint(e, "--listen") for e in listen]))
        if connect:
            conf.insert_json5("connect/endpoints", json.dumps([check_endpoint(e, "--connect") for e in connect]))
    except ConfigError:
        raise
    except Exception as exc:
        raise ConfigError(f"zenoh rejected the endpoints: {exc}") from None
    return conf


class OpenStopped(Exception):
    """:func:`open_session` gave up because a stop was requested (Ctrl-C, SIGTERM)."""


def open_session(conf: zenoh.Config, timeout_s: float = 10.0, retry_s: float = 0.2,
                 stop: threading.Event | None = None) -> "zenoh.Session":
    """``zenoh.open``, retried until ``timeout_s`` (a client started before its peer keeps trying),
    each attempt bounded; ``stop`` (when set) ends the attempts early.

    Raises:
        ConfigError: when no session could be opened in time (e.g. no coordinator at the endpoint).
        OpenStopped: when ``stop`` was set first.
    """
    import time

    from mission.timers import GiveUp, retry

    first = time.monotonic()
    deadline = first + timeout_s  # bounds one attempt in flight; retry() decides whether to try again
    last = "timed out"
    while True:
        if stop is not None and stop.is_set():
            raise OpenStopped("stop requested while opening the zenoh session")
        result: dict = {}

        def target():
            try:
                result["session"] = zenoh.open(conf)
            except Exception as exc:  # zenoh.ZError and friends
                result["error"] = exc

        thread = threading.Thread(target=target, daemon=True, name="zenoh-open")
        thread.start()
        attempt_end = time.monotonic() + max(0.5, deadline - time.monotonic())
        while thread.is_alive() and time.monotonic() < attempt_end and not (stop and stop.is_set()):
            thread.join(0.05)
        if stop is not None and stop.is_set():
            thread.join(5.0)  # an attempt in flight: let it finish, never leave a session behind
            if "session" in result:
                try:
                    result["session"].close()
                except Exception:
                    pass
            raise OpenStopped("stop requested while opening the zenoh session")
        if "session" in result:
            return result["session"]
        if "error" in result:
            last = str(result["error"]).splitlines()[0].split(" at /")[0]
        failed = time.monotonic()
        rule = retry(first, failed, failed, timeout_s, retry_s)  # the coordinator timeout [P-5.2]'s shape
        if isinstance(rule, GiveUp):
            raise ConfigError(f"could not open a zenoh session within {timeout_s:.0f} s: {last}")
        if stop is not None:
            if stop.wait(rule.until - failed):
                raise OpenStopped("stop requested while opening the zenoh session")
        else:
            time.sleep(rule.until - failed)


def close_session(session, entities: Sequence = (), timeout_s: float = 3.0) -> bool:
    """Undeclare ``entities`` (subscribers, tokens, queryables) and close ``session`` (None: leave
    it open, another node of the process still uses it), bounded.

    Returns:
        True if everything closed within ``timeout_s`` seconds (else it is left to process exit).
    """
    def target():
        for entity in entities:
            try:
                entity.undeclare()
            except Exception:
                pass
        if session is None:
            return
        try:
            session.close()
        except Exception:
            pass

    thread = threading.Thread(target=target, daemon=True, name="zenoh-close")
    thread.start()
    thread.join(timeout_s)
    return not thread.is_alive()


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port free right now on ``host`` (for tests and the one-host fleet)."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return sock.getsockname()[1]
