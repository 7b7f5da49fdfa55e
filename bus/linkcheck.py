"""Zenoh config files as diffbot reads them, and what went wrong when a session cannot open.

* ``load_config(path)``: the file's text with ``${VAR}`` / ``${VAR:-default}`` filled in
  from the environment (Zenoh itself does no substitution; comment lines are left alone),
  so the shipped configs work once ``DIFFBOT_ROUTER`` and ``DIFFBOT_CERTS`` are set; an
  unset variable, or a TLS file that does not exist, is an error naming the file and key.
* ``diagnose(conf)``: after ``zenoh.open`` failed (Zenoh says only "Unable to connect to
  any of [...]! Timeout"), probe each endpoint with the standard library and say why:
  refused, timed out, no route, a unix socket that is not there; for ``tls/`` the TLS
  handshake with the config's CA and certificate: unknown CA, name mismatch, certificate
  required (mutual TLS), certificate rejected. Stdlib only.
"""
from __future__ import annotations

import errno
import json
import os
import re
import socket
import ssl

import zenoh

_VAR = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)(?::-([^}]*))?\}")
#: the TLS keys that name files, and who needs each
TLS_FILES = ("root_ca_certificate", "listen_certificate", "listen_private_key",
             "connect_certificate", "connect_private_key")
PROBE_TIMEOUT_S = 3.0


class ConfigFileError(ValueError):
    pass


def expand(text: str, path: str, env=os.environ) -> str:
    """``${VAR}`` and ``${VAR:-default}`` replaced outside ``//`` comment lines."""
    out = []
    for n, line in enumerate(text.splitlines(keepends=True), 1):
        if not line.lstrip().startswith("//"):
            def sub(m: re.Match) -> str:
                value = env.get(m.group(1))
                if value is None or (value == "" and m.group(2) is not None):
                    if m.group(2) is None:
                        raise ConfigFileError(
                            f"{path}:{n}: ${{{m.group(1)}}} is not set (export {m.group(1)}=... "
                            "first; see docs/several-machines.md)")
                    return m.group(2)
                return value
            line = _VAR.sub(sub, line)
        out.append(line)
    return "".join(out)


def _get(conf: zenoh.Config, key: str):
    try:
        return json.loads(conf.get_json(key))
    except Exception:       # an unknown key
        return None


def load_config(path: str, env=None) -> zenoh.Config:
    """The Zenoh config in ``path``, variables filled in (from ``env``, default the
    process's environment), TLS files checked."""
    if not os.path.isfile(path):
        raise ConfigFileError(f"{path}: no such Zenoh config file")
    with open(path, encoding="utf-8") as f:
        text = expand(f.read(), path, os.environ if env is None else env)
    try:
        conf = zenoh.Config.from_json5(text)
    except Exception as exc:  # zenoh.ZError
        raise ConfigFileError(f"{path}: not a valid Zenoh config: {exc}") from None
    for key in TLS_FILES:
        value = _get(conf, f"transport/link/tls/{key}")
        if value and not os.path.isfile(value):
            raise ConfigFileError(
                f"{path}: transport.link.tls.{key}: {value}: no such file (make certificates "
                "with `diffbot certs --out DIR`, then export DIFFBOT_CERTS=DIR)")
    return conf


def _split(endpoint: str) -> tuple[str, str]:
    proto, _, rest = endpoint.partition("/")
    return proto, rest.split("#", 1)[0].split("?", 1)[0]


def _host_port(addr: str) -> tuple[str, int]:
    host, _, port = addr.rpartition(":")
    return host.strip("[]"), int(port)


def _tcp(host: str, port: int) -> tuple[socket.socket | None, str]:
    try:
        return socket.create_connection((host, port), timeout=PROBE_TIMEOUT_S), ""
    except socket.gaierror as exc:
        return None, f"cannot resolve {host!r} ({exc.strerror})"
    except ConnectionRefusedError:
        return None, ("connection refused (nothing listens there: is the router, or the plant, "
                      "running?)")
    except (socket.timeout, TimeoutError):
        return None, f"no answer within {PROBE_TIMEOUT_S:g} s (timeout: host down or filtered)"
    except OSError as exc:
        if exc.errno in (errno.ENETUNREACH, errno.EHOSTUNREACH):
            return None, f"no route to {host} ({exc.strerror})"
        return None, exc.strerror or str(exc)


def _tls_cause(exc: Exception, host: str) -> str:
    text = str(exc)
    if isinstance(exc, ssl.SSLCertVerificationError):
        msg = exc.verify_message or text
        if "mismatch" in msg.lower():
            return (f"name mismatch: the router's certificate does not name {host!r} in its "
                    "subjectAltName (make it with `diffbot certs --router ADDR`)")
        if "issuer" in msg or "self-signed" in msg or "self signed" in msg:
            return ("unknown CA: the router's certificate is not signed by the CA in "
                    "root_ca_certificate")
        if "expired" in msg:
            return "the router's certificate has expired"
        return f"the router's certificate was not accepted: {msg}"
    up = text.upper()
    if "CERTIFICATE_REQUIRED" in up:
        return ("certificate required: the router wants a client certificate (mutual TLS): "
                "set enable_mtls, connect_certificate and connect_private_key")
    if any(a in up for a in ("UNKNOWN_CA", "BAD_CERTIFICATE", "DECRYPT_ERROR",
                             "CERTIFICATE_UNKNOWN")):
        return ("the router rejected this client's certificate (unknown CA: not signed by "
                "the CA in the router's root_ca_certificate?)")
    if "WRONG_VERSION_NUMBER" in up or "RECORD_LAYER" in up or "EOF" in up:
        return ("the other end closed the connection in the TLS handshake: not a TLS "
                "endpoint (a tcp/ router?)")
    return f"TLS handshake failed: {text}"


def _probe_tls(conf: zenoh.Config, host: str, port: int) -> str:
    sock, why = _tcp(host, port)
    if sock is None:
        return why
    tls = _get(conf, "transport/link/tls") or {}
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname = tls.get("verify_name_on_connect", True) is not False
    try:
        if tls.get("root_ca_certificate"):
            ctx.load_verify_locations(tls["root_ca_certificate"])
        else:
            ctx.load_default_certs()
        if tls.get("connect_certificate") and tls.get("connect_private_key"):
            ctx.load_cert_chain(tls["connect_certificate"], tls["connect_private_key"])
    except (OSError, ssl.SSLError) as exc:
        sock.close()
        return f"cannot load this client's TLS files: {exc}"
    try:
        with ctx.wrap_socket(sock, server_hostname=host) as s:
            s.settimeout(1.0)
            try:         # TLS 1.3: a refused client certificate arrives as an alert now
                s.recv(1)
            except (socket.timeout, TimeoutError):
                pass
        return ("the TLS handshake succeeds: the router accepted this certificate, so it "
                "refused the session itself (access control? a Zenoh version mismatch?)")
    except ssl.SSLError as exc:
        return _tls_cause(exc, host)
    except (socket.timeout, TimeoutError):
        return (f"no TLS answer within {PROBE_TIMEOUT_S:g} s (timeout): not a TLS endpoint "
                "(a tcp/ router?), or a frozen router")
    except OSError as exc:
        return (f"the other end closed the connection in the TLS handshake ({exc}): not a "
                "TLS endpoint (a tcp/ router?)")


def probe(conf: zenoh.Config, endpoint: str) -> str:
    """Why a client cannot open a session to ``endpoint``, in a few words."""
    proto, addr = _split(endpoint)
    try:
        if proto == "unixsock-stream":
            if not os.path.exists(addr):
                return f"no socket file {addr} (is the plant running with this --endpoint?)"
            with socket.socket(socket.AF_UNIX) as s:
                s.settimeout(PROBE_TIMEOUT_S)
                s.connect(addr)
            return "the socket accepts connections, but no Zenoh session opened"
        host, port = _host_port(addr)
    except (ValueError, OSError) as exc:
        return getattr(exc, "strerror", None) or str(exc)
    if proto == "tls":
        return _probe_tls(conf, host, port)
    if proto == "tcp":
        sock, why = _tcp(host, port)
        if sock is None:
            return why
        if _speaks_tls(sock):
            return (f"{NOT_TLS_CLIENT}: connect to tls/{addr} with your role's TLS config "
                    "(diffbot/launch/configs/<role>_tls.json5, docs/several-machines.md)")
        return ("TCP connects, but no Zenoh session opened (the wrong port? refused by the "
                "router?)")
    return "cannot probe this kind of endpoint"


def _speaks_tls(sock: socket.socket) -> bool:
    """Whether the endpoint ``sock`` is connected to answers a TLS ClientHello with a TLS
    record (a ``tls/`` router dialled with ``tcp/``): the hello goes out, the first record
    header comes back, and the socket closes (the router logs one refused handshake). A plain Zenoh router waits for a
    frame the hello does not complete: no answer, no. Closes ``sock``."""
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname = False
    ctx.verify_mode = ssl.CERT_NONE
    out = ssl.MemoryBIO()
    tls = ctx.wrap_bio(ssl.MemoryBIO(), out)
    try:
        tls.do_handshake()
    except ssl.SSLWantReadError:
        pass
    try:
        sock.settimeout(1.0)
        sock.sendall(out.read())
        head = sock.recv(3)
        # a TLS record: content type handshake (22) or alert (21), version 3.x
        return len(head) >= 2 and head[0] in (21, 22) and head[1] == 3
    except OSError:
        return False
    finally:
        sock.close()


#: the probe's words for a client that dials ``tcp/`` at a TLS endpoint
NOT_TLS_CLIENT = "the endpoint speaks TLS and this client connects without (tcp/)"
#: probe results that retrying will not change: a TLS or protocol refusal, reported at once
#: (:func:`refusals`); "connection refused", "no socket file", timeouts and a successful TLS
#: handshake are not among them (the router may still be starting, or be slow)
REFUSALS = ("unknown CA", "name mismatch", "certificate required", "rejected this client's "
            "certificate", "has expired", "was not accepted", "closed the connection in the "
            "TLS handshake", "cannot load this client's TLS files", NOT_TLS_CLIENT)


def refusals(conf: zenoh.Config) -> list[str]:
    """The "endpoint: cause" lines of :func:`diagnose` if every endpoint the client may
    connect to refused it for good (a TLS or protocol mismatch); else [] (keep trying)."""
    lines = diagnose(conf)
    connect = _get(conf, "connect/endpoints")
    if not lines or not connect or not all(any(r in ln for r in REFUSALS) for ln in lines):
        return []
    return lines


def listen_problem(endpoint: str) -> str:
    """Why listening on ``endpoint`` fails: address in use, not this machine's, ..."""
    proto, addr = _split(endpoint)
    try:
        if proto == "unixsock-stream":
            if os.path.exists(addr):
                return f"{addr} exists (another plant? a stale socket file?)"
            return f"cannot create {addr}"
        host, port = _host_port(addr)
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        with socket.socket(family) as s:
            s.bind((host, port))
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            return "address already in use (another plant or router?)"
        if exc.errno == errno.EADDRNOTAVAIL:
            return f"{host} is not an address of this machine"
        return exc.strerror or str(exc)
    except ValueError as exc:
        return str(exc)
    return "the address is free: see the Zenoh error"


def diagnose(conf: zenoh.Config) -> list[str]:
    """One "endpoint: cause" line per endpoint of ``conf`` (connect, else listen)."""
    connect = _get(conf, "connect/endpoints") or []
    if isinstance(connect, dict):       # per-mode endpoints
        connect = connect.get(_get(conf, "mode") or "client", [])
    if connect:
        return [f"cannot connect to {e}: {probe(conf, e)}" for e in connect]
    listen = _get(conf, "listen/endpoints") or []
    if isinstance(listen, dict):
        listen = listen.get(_get(conf, "mode") or "router", [])
    return [f"cannot listen on {e}: {listen_problem(e)}" for e in listen]
