"""Why a session could not connect: one probe of each connect endpoint (stdlib only).

Zenoh reports every failed connect the same way ("Unable to connect to any of [...].
Timeout!"), whether nothing listens, the router's TLS refused the client's certificate,
or the router refused its user and password. After such a failure the programs probe
the endpoint once to name the cause: a plain TCP connect (unreachable?), then, for a
`tls/` endpoint, a TLS handshake with the config's own CA, certificate and key (the
router's alert names what it refused). A handshake that passes leaves the Zenoh session
itself refused: with a user/password in the config, that is the authentication.
"""

from __future__ import annotations

import base64
import contextlib
import os
import socket
import ssl
import tempfile
from collections.abc import Iterator
from typing import Any

PROBE_TIMEOUT = 2.0  # s: for the TCP connect and the TLS handshake
SETTLE = 1.0  # s: after the handshake, how long to wait for a refusal of the certificate


def split_endpoint(endpoint: str) -> tuple[str, str, int] | None:
    """`tls/host:port` (metadata `?...`, config `#...` ignored) -> (proto, host, port);
    None for other forms (unix sockets, no port)."""
    proto, _, rest = endpoint.partition("/")
    addr = rest.split("?")[0].split("#")[0]
    host, sep, port = addr.rpartition(":")
    if not sep or not port.isdigit():
        return None
    return proto, host.strip("[]"), int(port)


def alert(exc: ssl.SSLError) -> str | None:
    """The TLS alert the peer sent ('unknown ca', 'certificate required'), if any."""
    reason = getattr(exc, "reason", None) or ""
    if "ALERT_" not in reason:
        return None
    return reason.split("ALERT_", 1)[1].replace("_", " ").lower()


@contextlib.contextmanager
def pem_file(tls: dict, name: str) -> Iterator[str | None]:
    """The path of PEM `name` of the TLS section: the file it names, or its `_base64`
    form written to a private temporary file; None when neither is set."""
    if tls.get(name):
        yield str(tls[name])
        return
    b64 = tls.get(f"{name}_base64")
    if not b64:
        yield None
        return
    fd, path = tempfile.mkstemp(suffix=".pem")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(base64.b64decode(b64))
        yield path
    finally:
        os.unlink(path)


def tls_context(tls: dict, verify_name: bool) -> tuple[ssl.SSLContext, str | None]:
    """A client context as Zenoh's would be from the same TLS section; the client
    certificate's path (None: the client shows none)."""
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname = verify_name
    with pem_file(tls, "root_ca_certificate") as ca:
        if ca:
            ctx.load_verify_locations(ca)
        else:
            ctx.load_default_certs()
    cert = None
    if tls.get("enable_mtls"):
        with pem_file(tls, "connect_certificate") as cert, \
                pem_file(tls, "connect_private_key") as key:
            if cert and key:
                ctx.load_cert_chain(cert, key)
            cert = tls.get("connect_certificate") or ("connect_certificate_base64"
                                                      if cert else None)
    return ctx, cert


def refused_by_tls(name: str, cert: str | None) -> str:
    shown = (f"it does not accept the certificate {cert} (signed by another CA? expired?)"
             if cert else "this config shows it no client certificate (transport/link/tls: "
             "enable_mtls, connect_certificate, connect_private_key)")
    return f"TLS refused by the router (alert: {name}): {shown}"


def after_transport(auth: dict) -> str:
    """The cause once the transport (TCP, TLS) was accepted: the Zenoh session refused."""
    user = (auth or {}).get("user")
    if user:
        return (f"authentication refused by the router (user {user}: wrong user name or "
                "password? transport/auth/usrpwd)")
    return ("the router accepted the connection but refused the Zenoh session (does it "
            "want a user and password? transport/auth/usrpwd)")


def probe_tls(sock: socket.socket, host: str, tls: dict, auth: dict) -> str:
    if tls.get("enable_mtls") and not all(
            tls.get(k) or tls.get(f"{k}_base64")
            for k in ("connect_certificate", "connect_private_key")):
        return ("the config turns mTLS on without a client certificate and key "
                "(transport/link/tls: connect_certificate, connect_private_key)")
    try:
        ctx, cert = tls_context(tls, tls.get("verify_name_on_connect", True) is not False)
    except (OSError, ssl.SSLError, ValueError) as exc:
        return f"cannot use the TLS files of the config: {exc}"
    try:
        with ctx.wrap_socket(sock, server_hostname=host) as s:
            s.settimeout(SETTLE)  # TLS 1.3: a refused client certificate comes after
            try:
                s.recv(1)
            except TimeoutError:
                return after_transport(auth)
            except ssl.SSLError as exc:
                name = alert(exc)
                if name:
                    return refused_by_tls(name, cert)
                return f"TLS failed after the handshake: {exc.reason or exc}"
            return refused_by_tls("none, the connection closed", cert)
    except ssl.SSLCertVerificationError as exc:
        return (f"the router's TLS certificate is not accepted: {exc.verify_message} (CA "
                f"{tls.get('root_ca_certificate') or 'of the system'}; name {host})")
    except ssl.SSLError as exc:
        name = alert(exc)
        if name:
            return refused_by_tls(name, cert)
        return f"no TLS at this endpoint ({exc.reason or exc}): is it a tcp/ port?"
    except TimeoutError:
        return "the router did not complete the TLS handshake in time"


def speaks_tls(sock: socket.socket, host: str) -> bool:
    """Whether the server answers a TLS client hello (with a handshake or an alert)."""
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname, ctx.verify_mode = False, ssl.CERT_NONE
    sock.settimeout(SETTLE)  # a Zenoh TCP link waits for more bytes: no answer
    try:
        with ctx.wrap_socket(sock, server_hostname=host):
            return True
    except ssl.SSLError as exc:
        return alert(exc) is not None
    except OSError:
        return False


def probe(endpoint: str, tls: dict | None = None, auth: dict | None = None,
          timeout: float = PROBE_TIMEOUT, mode: str = "client") -> tuple[bool, str]:
    """(reached, cause) for one endpoint: `reached` False when nothing answered there.
    A client's endpoint is its router; a peer's is another peer (a service, say), and
    what does not answer there is named as such."""
    parts = split_endpoint(endpoint)
    if parts is None or parts[0] not in ("tcp", "tls"):
        return False, "no answer"
    proto, host, port = parts
    try:
        sock = socket.create_connection((host, port), timeout=timeout)
    except socket.gaierror:
        return False, f"unknown host {host} (check -e/--connect)"
    except ConnectionRefusedError:
        if mode != "client":
            return False, (f"nothing listens at {proto}/{host}:{port} (is the service or "
                           "peer there running? check -e/--connect)")
        return False, (f"router unreachable: connection refused at {host}:{port} (is the "
                       "router running? check -e/--connect)")
    except OSError as exc:
        why = "no answer" if isinstance(exc, TimeoutError) else exc.strerror or str(exc)
        if mode != "client":
            return False, f"no answer at {proto}/{host}:{port}: {why} (check -e/--connect)"
        return False, f"router unreachable: {why} at {host}:{port} (check -e/--connect)"
    with sock:
        if proto == "tls":
            return True, probe_tls(sock, host, tls or {}, auth or {})
        if speaks_tls(sock, host):
            return True, (f"the router speaks TLS at {host}:{port}, not plain TCP: connect "
                          f"with tls/{host}:{port} and the deployment's certificates")
    return True, after_transport(auth or {})


def why_refused(conf: Any, endpoints: list[str]) -> tuple[bool, str]:
    """(any endpoint reached, the causes) for a zenoh.Config that failed to connect."""
    import json

    def get(path: str) -> Any:
        try:
            return json.loads(conf.get_json(path))
        except Exception:  # noqa: BLE001 - a section this Zenoh does not know
            return None

    tls, auth = get("transport/link/tls") or {}, get("transport/auth/usrpwd") or {}
    mode = get("mode") or "peer"
    found = [(e, *probe(e, tls, auth, mode=mode)) for e in endpoints]
    reached = [f for f in found if f[1]]
    shown = reached or found
    if len(shown) == 1:
        return bool(reached), shown[0][2]
    return bool(reached), "; ".join(f"{e}: {c}" for e, _, c in shown)
