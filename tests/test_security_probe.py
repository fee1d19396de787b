"""The connect-failure probe (service/wire/refusal.py) on real loopback sockets: how an
endpoint is read, nothing listening, a listener that takes the connection and says
nothing, and a TLS server that wants a client certificate (Python's ssl as the router)."""

from __future__ import annotations

import socket
import ssl
import threading

from secure_kit import make_certs

from zenoh_track.wire import free_port
from zenoh_track.wire.refusal import probe, split_endpoint


def test_endpoints_are_read_with_their_metadata_and_ipv6():
    assert split_endpoint("tls/router:7447") == ("tls", "router", 7447)
    assert split_endpoint("tcp/127.0.0.1:7447?prio=1#iface=lo") == ("tcp", "127.0.0.1", 7447)
    assert split_endpoint("tcp/[::1]:7447") == ("tcp", "::1", 7447)
    assert split_endpoint("unixsock-stream//tmp/zenoh.sock") is None


def test_nothing_listening_is_unreachable():
    port = free_port()
    reached, cause = probe(f"tls/127.0.0.1:{port}")
    assert not reached and f"connection refused at 127.0.0.1:{port}" in cause


def serve_once(handle) -> tuple[int, threading.Thread]:
    srv = socket.create_server(("127.0.0.1", 0))
    port = srv.getsockname()[1]

    def run() -> None:
        with srv:
            conn, _ = srv.accept()
            handle(conn)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return port, t


def test_a_silent_listener_was_reached():
    done = threading.Event()
    port, t = serve_once(lambda c: (c.recv(4096), done.wait(5), c.close()))
    reached, cause = probe(f"tcp/127.0.0.1:{port}", auth={"user": "track-viewer"})
    done.set()
    t.join(10)
    assert reached and "authentication refused by the router (user track-viewer" in cause


def test_a_tls_server_that_wants_a_certificate_refuses_one_without(tmp_path):
    certs = make_certs(tmp_path / "c")
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    ctx.load_cert_chain(certs / "router.pem", certs / "router-key.pem")
    ctx.load_verify_locations(certs / "ca.pem")
    ctx.verify_mode = ssl.CERT_REQUIRED

    def handle(conn: socket.socket) -> None:
        try:
            with ctx.wrap_socket(conn, server_side=True) as s:
                s.recv(1)
        except (ssl.SSLError, OSError):
            pass

    port, t = serve_once(handle)
    reached, cause = probe(f"tls/127.0.0.1:{port}",
                           tls={"root_ca_certificate": str(certs / "ca.pem")})
    t.join(10)
    assert reached and "TLS refused by the router (alert: certificate required)" in cause
    assert "shows it no client certificate" in cause
