"""CURVE on loopback with generated keys: the right keys connect, wrong ones are refused."""

import logging
import threading
import time

import pytest
import zmq
import zmq.auth

from ipc import messages as m
from ipc.transport import CurveClient, CurveServer, Publisher, ReplyServer, RequestClient, RequestTimeout, Subscriber

pytestmark = [
    pytest.mark.timeout(60),
    pytest.mark.skipif(not zmq.has("curve"), reason="libzmq built without CURVE"),
]

ANY_PORT = "tcp://127.0.0.1:*"


@pytest.fixture
def keys(tmp_path):
    """Cert files as zmq.auth writes them: server, an authorised client, a stranger."""
    for name in ("server", "client", "stranger"):
        (tmp_path / name).mkdir()
        zmq.auth.create_certificates(tmp_path / name, name)
    authorized = tmp_path / "authorized"
    authorized.mkdir()
    (authorized / "client.key").write_bytes((tmp_path / "client" / "client.key").read_bytes())
    return tmp_path


def client_keys(keys, name: str, server: str = "server") -> CurveClient:
    return CurveClient.from_files(keys / name / f"{name}.key_secret", keys / server / f"{server}.key")


@pytest.fixture
def server(keys):
    curve = CurveServer.from_files(keys / "server" / "server.key_secret", keys / "authorized")
    srv = ReplyServer(ANY_PORT, {m.StatusRequest: lambda r: m.StatusReply(request_id=r.request_id)}, curve=curve)
    stop = threading.Event()
    thread = threading.Thread(target=srv.serve_forever, args=(stop, 0.02), daemon=True)
    thread.start()
    yield srv
    stop.set()
    thread.join(timeout=5)
    srv.close()


def test_authorised_client_is_served(keys, server):
    with RequestClient(server.endpoint, timeout_s=3.0, curve=client_keys(keys, "client")) as client:
        assert client.request(m.StatusRequest(request_id=21)).request_id == 21


def test_unknown_client_key_is_refused(keys, server, caplog):
    caplog.set_level(logging.WARNING, logger="ipc.transport")
    with RequestClient(server.endpoint, timeout_s=0.3, attempts=2, curve=client_keys(keys, "stranger")) as client:
        with pytest.raises(RequestTimeout):
            client.request(m.StatusRequest())
    assert any("refused a CURVE client with unknown public key" in r.getMessage() for r in caplog.records)


def test_wrong_server_key_is_refused(keys, server):
    stranger = client_keys(keys, "client", server="stranger")
    with RequestClient(server.endpoint, timeout_s=0.3, attempts=2, curve=stranger) as client:
        with pytest.raises(RequestTimeout):
            client.request(m.StatusRequest())


def test_plain_client_is_refused(server):
    with RequestClient(server.endpoint, timeout_s=0.3, attempts=1) as client, pytest.raises(RequestTimeout):
        client.request(m.StatusRequest())


def test_curve_publisher(keys):
    curve = CurveServer.from_files(keys / "server" / "server.key_secret", keys / "authorized")
    with Publisher(ANY_PORT, source="estimates", heartbeat_period_s=0.05, curve=curve) as pub:
        with (
            Subscriber(pub.endpoint, curve=client_keys(keys, "client")) as good,
            Subscriber(pub.endpoint, curve=client_keys(keys, "stranger")) as bad,
        ):
            deadline = time.monotonic() + 5.0
            while good.last_heartbeat is None and time.monotonic() < deadline:
                time.sleep(0.02)
            assert good.last_heartbeat is not None and good.last_heartbeat.source == "estimates"
            assert bad.last_heartbeat is None and bad.received == 0


def test_key_checks(keys):
    with pytest.raises(ValueError, match="holds no secret key"):
        CurveServer.from_files(keys / "server" / "server.key", keys / "authorized")
    (keys / "empty").mkdir()
    with pytest.raises(ValueError, match="CurveServer.authorized_clients: expected at least one"):
        CurveServer.from_files(keys / "server" / "server.key_secret", keys / "empty")
    public, secret = zmq.curve_keypair()
    with pytest.raises(ValueError, match="CurveClient.server_public_key: expected a 40-byte Z85 CURVE key"):
        CurveClient(public, secret, b"short")
