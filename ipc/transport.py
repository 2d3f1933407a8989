"""ZeroMQ transport helpers: every process of the toolkit talks through these four classes.

- ``Publisher`` (PUB, binds): publishes messages and a ``Heartbeat`` every period.
- ``Subscriber`` (SUB, connects): latest-message semantics. A receiver thread drains
  the socket as fast as messages arrive and keeps only the newest data message, so a
  slow consumer gets the newest frame, never a backlog, and memory stays bounded
  whatever the producer's rate. It tracks the age of the last message and logs (and
  calls back) when the publisher goes silent and when it comes back.
- ``RequestClient`` (REQ, connects): request/reply with a timeout and retries; after a
  timeout it closes and reopens its socket ("lazy pirate"), so it never hangs on a
  dead peer. An ``ErrorReply`` is raised as ``RemoteError``.
- ``ReplyServer`` (REP, binds): dispatches requests by type to handlers and answers
  every request, malformed ones with an ``ErrorReply``, then keeps serving.

A service is a thin loop around them, e.g. the perception service::

    with Subscriber(endpoints.FRAMES, accept=(RGBDFrame,)) as frames, \\
         Publisher(endpoints.ESTIMATES, source="perception") as estimates, \\
         ReplyServer(endpoints.PERCEPTION_CONTROL, handlers) as control:
        while not stop.is_set():
            control.serve_once(timeout_s=0)
            frame = frames.recv_latest(timeout_s=0.05)
            if frame is not None:
                estimates.publish(tracker.step(frame))

Sockets use linger 0 (closing never blocks), ``zmq.MAXMSGSIZE`` at the codec's message
cap, and small high-water marks. Optional CURVE encryption and client authentication
(``CurveServer`` for binding sides, ``CurveClient`` for connecting sides) is for
controllers on other machines; a CURVE server runs its own context and ZAP
authenticator thread, which accepts only the listed client public keys.

Each object is used from one thread (the one that calls its methods); ``Publisher``
also sends heartbeats from a thread of its own, serialised with ``publish`` by a lock.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import zmq
import zmq.auth
from zmq.auth.thread import ThreadAuthenticator

from ipc.codec import DEFAULT_LIMITS, MESSAGE_TYPES, Limits, ProtocolError, _one_line, decode, encode, peek_type
from ipc.messages import ErrorReply, Heartbeat

log = logging.getLogger(__name__)

__all__ = [
    "AUTHORIZED_CLIENTS_DIR",
    "HEARTBEAT_PERIOD_S",
    "HWM",
    "REQUEST_ATTEMPTS",
    "REQUEST_TIMEOUT_S",
    "STALE_AFTER_S",
    "CurveClient",
    "CurveKeys",
    "CurveServer",
    "Publisher",
    "RemoteError",
    "ReplyServer",
    "RequestClient",
    "RequestTimeout",
    "Subscriber",
    "create_key_directory",
]

#: Seconds between two heartbeats of a publisher.
HEARTBEAT_PERIOD_S = 1.0
#: Fewest seconds between two heartbeats: heartbeats sent more often fill a subscriber's
#: queue (``HWM`` messages) and crowd out the frames and estimates they stand beside.
MIN_HEARTBEAT_PERIOD_S = 0.05
#: Seconds without any message after which a subscriber reports its publisher gone.
STALE_AFTER_S = 3.0
#: Seconds a client waits for each reply attempt, and attempts before giving up.
REQUEST_TIMEOUT_S = 1.0
REQUEST_ATTEMPTS = 3
#: High-water mark (whole messages queued per peer) of publishers and subscribers:
#: small, since only the newest message matters and a 640x480 frame is 1.5 MB.
HWM = 4

_ZMTP_HEARTBEAT_MS = 1000  # ZMTP pings: drop a half-open TCP connection so ZeroMQ reconnects


class RequestTimeout(TimeoutError):
    """No reply after every attempt: the peer is dead, busy, or refuses our CURVE keys."""


class RemoteError(RuntimeError):
    """The server answered with an ErrorReply; ``reply`` holds it, ``code`` its code."""

    def __init__(self, reply: ErrorReply):
        super().__init__(f"{reply.code}: {reply.message}")
        self.reply = reply
        self.code = reply.code


def _check_key(name: str, key: bytes) -> bytes:
    if not isinstance(key, bytes) or len(key) != 40:
        got = f"{len(key)} bytes" if isinstance(key, bytes) else type(key).__name__  # never the key: it may be secret
        raise ValueError(f"{name}: expected a 40-byte Z85 CURVE key, got {got}")
    return key


@dataclass(frozen=True)
class CurveServer:
    """CURVE keys of a binding socket: its key pair and the client public keys it accepts.

    Keys are 40-byte Z85 strings (``zmq.curve_keypair()``, or cert files from
    ``zmq.auth.create_certificates``).
    """

    public_key: bytes
    secret_key: bytes
    authorized_clients: frozenset

    def __post_init__(self):
        _check_key("CurveServer.public_key", self.public_key)
        _check_key("CurveServer.secret_key", self.secret_key)
        clients = frozenset(self.authorized_clients)
        if not clients:
            raise ValueError("CurveServer.authorized_clients: expected at least one client public key")
        for key in clients:
            _check_key("CurveServer.authorized_clients", key)
        object.__setattr__(self, "authorized_clients", clients)

    @classmethod
    def from_files(cls, secret_key_file: str | Path, authorized_clients_dir: str | Path) -> CurveServer:
        """Load the server's ``.key_secret`` cert and every ``.key`` cert in a directory."""
        public, secret = zmq.auth.load_certificate(secret_key_file)
        if secret is None:
            raise ValueError(f"CurveServer: {secret_key_file} holds no secret key")
        return cls(public, secret, frozenset(zmq.auth.load_certificates(authorized_clients_dir)))


@dataclass(frozen=True)
class CurveClient:
    """CURVE keys of a connecting socket: its key pair and the server's public key."""

    public_key: bytes
    secret_key: bytes
    server_public_key: bytes

    def __post_init__(self):
        _check_key("CurveClient.public_key", self.public_key)
        _check_key("CurveClient.secret_key", self.secret_key)
        _check_key("CurveClient.server_public_key", self.server_public_key)

    @classmethod
    def from_files(cls, secret_key_file: str | Path, server_public_key_file: str | Path) -> CurveClient:
        """Load the client's ``.key_secret`` cert and the server's public ``.key`` cert."""
        public, secret = zmq.auth.load_certificate(secret_key_file)
        if secret is None:
            raise ValueError(f"CurveClient: {secret_key_file} holds no secret key")
        server_public, _ = zmq.auth.load_certificate(server_public_key_file)
        return cls(public, secret, server_public)


#: Layout of a key directory (``CurveKeys.from_directory``, ``create_key_directory``).
SERVER_SECRET_FILE = "server.key_secret"
SERVER_PUBLIC_FILE = "server.key"
AUTHORIZED_CLIENTS_DIR = "authorized_clients"
CLIENTS_DIR = "clients"


@dataclass(frozen=True)
class CurveKeys:
    """The CURVE keys of one toolkit process: ``server`` for the sockets it binds (PUB, REP),
    ``client`` for those it connects (SUB to another toolkit process's publisher).

    The toolkit's processes share one key pair (the "server" pair): each accepts the clients
    listed in ``authorized_clients`` and connects to the others as a client with that same
    pair, so the directory also lists the server's own public key as an authorised client.
    """

    server: CurveServer
    client: CurveClient

    @classmethod
    def from_directory(cls, directory: str | Path) -> CurveKeys:
        """Load a key directory laid out as ``create_key_directory`` writes it::

            DIR/server.key_secret         the services' key pair (keep it secret)
            DIR/server.key                its public key (give it to every client)
            DIR/authorized_clients/*.key  public keys of the clients allowed to connect

        raises ValueError (one line) naming a missing or unreadable file
        """
        directory = Path(directory)
        secret = directory / SERVER_SECRET_FILE
        authorized = directory / AUTHORIZED_CLIENTS_DIR
        if not secret.is_file():
            raise ValueError(f"CURVE keys: {secret} not found (create a key directory with python -m launch_scripts.curve_keys)")
        if not authorized.is_dir():
            raise ValueError(f"CURVE keys: {authorized} not found: it holds the public keys of the authorised clients")
        try:
            server = CurveServer.from_files(secret, authorized)
        except (OSError, ValueError) as e:
            raise ValueError(f"CURVE keys in {directory}: {e}") from None
        return cls(server, CurveClient(server.public_key, server.secret_key, server.public_key))


def create_key_directory(directory: str | Path, clients=("controller",)) -> list[Path]:
    """Write a key directory for ``CurveKeys.from_directory``: a new server key pair, its
    public key among the authorised clients, and for each name in ``clients`` a key pair in
    ``DIR/clients/NAME.key(_secret)`` whose public key is authorised too.

    An existing server key pair or client pair is kept (so that clients stay authorised);
    returns the files written. Hand ``clients/NAME.key_secret`` and ``server.key`` to the
    client NAME, then delete its secret file here.
    raises ValueError for a client name that is not a plain file name
    """
    directory = Path(directory)
    authorized = directory / AUTHORIZED_CLIENTS_DIR
    client_dir = directory / CLIENTS_DIR
    written = []
    for name in clients:
        if not name or name == "server" or Path(name).name != name or name.startswith("."):
            raise ValueError(f"client name: expected a plain file name other than 'server', got {name!r}")
    for folder in (directory, authorized, client_dir):
        folder.mkdir(parents=True, exist_ok=True)
    pairs = [(directory, "server"), *((client_dir, name) for name in clients)]
    for folder, name in pairs:
        public = folder / f"{name}.key"
        if not (folder / f"{name}.key_secret").is_file():
            zmq.auth.create_certificates(folder, name)
            written += [public, folder / f"{name}.key_secret"]
            (folder / f"{name}.key_secret").chmod(0o600)
        copy = authorized / f"{name}.key"
        copy.write_bytes(public.read_bytes())
        written.append(copy)
    return written


class _WarningEvery:
    """Logs a warning at most once per ``period_s`` seconds and says how many were not logged,
    so that a peer sending garbage in a loop cannot flood the log (every one is still counted)."""

    def __init__(self, period_s: float = 1.0):
        self.period_s = period_s
        self._next = -math.inf
        self._suppressed = 0

    def __call__(self, message: str, *args) -> None:
        now = time.monotonic()
        if now < self._next:
            self._suppressed += 1
            return
        if self._suppressed:
            message += f" ({self._suppressed} more like it in the last {self.period_s:g} s not logged)"
        self._suppressed = 0
        self._next = now + self.period_s
        log.warning(message, *args)


class _AuthorizedKeys:
    """ZAP credentials provider (pyzmq's callback protocol): accept listed client keys only."""

    def __init__(self, keys: frozenset, endpoint: str):
        self.keys, self.endpoint = keys, endpoint

    def callback(self, domain: str, key: bytes) -> bool:
        if key in self.keys:
            return True
        log.warning("%s: refused a CURVE client with unknown public key %s", self.endpoint, key.decode("ascii", "replace"))
        return False


class _Socket:
    """A configured socket with its context; owns a private context only for a CURVE server."""

    def __init__(self, kind: int, endpoint: str, *, bind: bool, limits: Limits, curve, hwm: int | None = None):
        self.auth = None
        if isinstance(curve, CurveServer):
            # The ZAP authenticator is per context; a private one keeps servers independent.
            self.context = zmq.Context()
            self.auth = ThreadAuthenticator(self.context)
            self.auth.start()
            self.auth.configure_curve_callback("*", credentials_provider=_AuthorizedKeys(curve.authorized_clients, endpoint))
        else:
            self.context = zmq.Context.instance()
        try:
            self.sock = self.context.socket(kind)
            self.sock.setsockopt(zmq.LINGER, 0)
            self.sock.setsockopt(zmq.MAXMSGSIZE, limits.max_message_bytes)
            if hwm is not None:
                self.sock.setsockopt(zmq.SNDHWM, hwm)
                self.sock.setsockopt(zmq.RCVHWM, hwm)
            if isinstance(curve, CurveServer):
                self.sock.curve_secretkey = curve.secret_key
                self.sock.curve_publickey = curve.public_key
                self.sock.curve_server = True
            elif isinstance(curve, CurveClient):
                self.sock.curve_secretkey = curve.secret_key
                self.sock.curve_publickey = curve.public_key
                self.sock.curve_serverkey = curve.server_public_key
            elif curve is not None:
                raise ValueError(f"curve: expected CurveServer, CurveClient or None, got {type(curve).__name__}")
            if bind:
                self.sock.bind(endpoint)
            else:
                self.sock.setsockopt(zmq.HEARTBEAT_IVL, _ZMTP_HEARTBEAT_MS)
                self.sock.setsockopt(zmq.HEARTBEAT_TIMEOUT, 3 * _ZMTP_HEARTBEAT_MS)
                self.sock.connect(endpoint)
        except (zmq.ZMQError, ValueError) as e:
            self.close()
            raise ValueError(f"{endpoint}: cannot {'bind' if bind else 'connect'} ({e})") from None
        # The endpoint actually bound: resolves a wildcard port such as tcp://127.0.0.1:*.
        self.endpoint = self.sock.getsockopt_string(zmq.LAST_ENDPOINT) if bind else endpoint

    def close(self) -> None:
        if getattr(self, "sock", None) is not None:
            self.sock.close(linger=0)
            self.sock = None
        if self.auth is not None:
            self.auth.stop()
            self.auth = None
            self.context.term()


def _recv_message(sock: zmq.Socket, limits: Limits, flags: int = 0) -> list:
    """Receive one multipart message as zmq.Frames (zero-copy), within ``limits``.

    ZeroMQ delivers all parts at once; parts past the caps are received and dropped so
    the socket is left at a message boundary, then ProtocolError is raised.
    Raises zmq.Again when ``flags`` has NOBLOCK and nothing is waiting.
    """
    frame = sock.recv(flags, copy=False)
    frames, count, total = [frame], 1, len(frame)
    while frame.more:
        frame = sock.recv(copy=False)
        count += 1
        total += len(frame)
        if count <= limits.max_frames and total <= limits.max_message_bytes:
            frames.append(frame)
    if count > limits.max_frames:
        raise ProtocolError(f"message has {count} frames, over the limit of {limits.max_frames}")
    if total > limits.max_message_bytes:
        raise ProtocolError(f"message of {total} bytes exceeds the limit of {limits.max_message_bytes}")
    return frames


class Publisher:
    """PUB socket that binds ``endpoint`` and publishes messages plus heartbeats.

    endpoint : e.g. ``ipc.endpoints.ESTIMATES``, or ``tcp://127.0.0.1:*`` for a free port
        (``endpoint`` then tells the one bound)
    source : name sent in heartbeats, e.g. "perception"
    heartbeat_period_s : seconds between heartbeats, sent from a background thread
    depth_scale : send RGBDFrame depth as uint16 with this many units per metre
        (``codec.encode``); None sends float32 metres
    hwm : messages queued per subscriber before new ones are dropped for it
    limits : caps that subscribers keep; a larger message is refused by ``publish``
    curve : CurveServer to encrypt and accept only listed subscribers, or None

    ``publish`` never blocks: a subscriber that cannot keep up loses messages (its
    Subscriber keeps the newest anyway).
    """

    def __init__(
        self,
        endpoint: str,
        *,
        source: str,
        heartbeat_period_s: float = HEARTBEAT_PERIOD_S,
        depth_scale: float | None = None,
        hwm: int = HWM,
        limits: Limits = DEFAULT_LIMITS,
        curve: CurveServer | None = None,
    ):
        Heartbeat(source=source, period_s=heartbeat_period_s)  # validates both before binding
        if heartbeat_period_s < MIN_HEARTBEAT_PERIOD_S:
            raise ValueError(f"heartbeat period: expected at least {MIN_HEARTBEAT_PERIOD_S} s (more often, heartbeats "
                             f"crowd the messages out of subscribers' queues), got {heartbeat_period_s:g} s")
        self.source = source
        self.limits = limits
        self.heartbeat_period_s = float(heartbeat_period_s)
        self.depth_scale = depth_scale
        self._socket = _Socket(zmq.PUB, endpoint, bind=True, limits=limits, curve=curve, hwm=hwm)
        self.endpoint = self._socket.endpoint
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._beat_thread = threading.Thread(target=self._beat, name=f"heartbeat {self.endpoint}", daemon=True)
        self._beat_thread.start()
        log.info("%s: publishing as %r", self.endpoint, source)

    def publish(self, msg) -> None:
        """Encode and send ``msg`` (any message type); raises ProtocolError if it cannot travel:
        among others, a message larger than ``limits.max_message_bytes``, which subscribers
        refuse (ZeroMQ then drops their connection without a word, so it is not sent)."""
        frames = encode(msg, depth_scale=self.depth_scale)
        size = sum(memoryview(f).nbytes for f in frames)
        if size > self.limits.max_message_bytes:
            raise ProtocolError(f"{self.endpoint}: {type(msg).__name__} message of {size} bytes exceeds the "
                                f"{self.limits.max_message_bytes}-byte message limit subscribers keep; not sent")
        with self._lock:
            if self._socket.sock is None:
                raise ValueError(f"{self.endpoint}: publisher is closed")
            self._socket.sock.send_multipart(frames, copy=False)

    def _beat(self) -> None:
        seq = 0
        while True:
            beat = Heartbeat(source=self.source, seq=seq, timestamp_s=time.time(), period_s=self.heartbeat_period_s)
            with self._lock:
                if self._socket.sock is None:
                    return
                self._socket.sock.send_multipart(encode(beat))
            seq += 1
            if self._stop.wait(self.heartbeat_period_s):
                return

    def close(self) -> None:
        """Stop heartbeats and close the socket; queued messages are dropped."""
        self._stop.set()
        self._beat_thread.join()
        with self._lock:
            self._socket.close()

    def __enter__(self) -> Publisher:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Subscriber:
    """SUB socket that connects to a publisher and hands out only the newest message.

    endpoint : the publisher's endpoint, e.g. ``ipc.endpoints.FRAMES``
    accept : message classes to keep, e.g. ``(RGBDFrame,)``; others are dropped and counted
        as ``malformed``. None keeps every type. Heartbeats are always consumed here, never
        returned.
    stale_after_s : seconds without any message (data or heartbeat) after which the
        publisher counts as gone (three heartbeat periods instead, if its heartbeats
        announce a longer period): logged as a warning and ``on_liveness(False, age_s)``
        is called; when messages flow again, logged and ``on_liveness(True, gap_s)``.
    on_restart : called as ``on_restart(previous, beat)`` with two Heartbeats when the
        publisher restarted (a new ``source`` name, or ``seq`` went back) while messages
        kept flowing. A restart seen in the first heartbeat after a silence is part of
        that silence's ``on_liveness(True, gap_s)`` and not reported again, so that one
        event of the stream is reported once.
        Both callbacks run on the receiver thread, in the order the events happened: keep them short.
    hwm, limits, curve : queue size, decoder caps, CurveClient or None
    keep_recent : how many data messages no longer waiting (taken by ``recv_latest``, or
        skipped for a newer one) to keep for ``recent()``, newest last; 0 keeps none

    Every message is decoded on the receiver thread as it arrives, so a malformed one is
    counted whether or not a newer one replaces it. Counters (ints, read any time):
    ``received`` (messages of any type), ``skipped`` (data messages, decoded and valid,
    replaced by a newer one before ``recv_latest`` took them), ``malformed`` (dropped as
    ProtocolError, or of a type not in ``accept``; logged at most once a second, with how
    many were not, so that a publisher sending garbage cannot flood the log), ``reconnects``
    (connections lost and opened again);
    ``last_malformed`` is the last malformed message's error, one line ("" before any).

    Connections: libzmq drops a connection whose peer sends a frame larger than the
    message cap (``ZMQ_MAXMSGSIZE``) and, for a connecting socket, never reconnects it
    (it counts as a protocol error). The receiver thread watches the socket's
    disconnections (a socket monitor) and replaces the socket with a new one connected to
    the same endpoint, so messages flow again from the same or a restarted publisher
    within libzmq's reconnect interval (0.1 s).

    Arrival times (``time.monotonic()``, None before the first), so a consumer can tell
    how old its data is: ``data_arrived_at`` of the newest data message received,
    ``taken_arrived_at`` of the message ``recv_latest`` returned last.
    """

    def __init__(
        self,
        endpoint: str,
        *,
        accept: tuple[type, ...] | None = None,
        stale_after_s: float = STALE_AFTER_S,
        on_liveness: Callable[[bool, float], None] | None = None,
        on_restart: Callable[[Heartbeat, Heartbeat], None] | None = None,
        hwm: int = HWM,
        limits: Limits = DEFAULT_LIMITS,
        curve: CurveClient | None = None,
        keep_recent: int = 0,
    ):
        if not (math.isfinite(stale_after_s) and stale_after_s > 0):
            raise ValueError(f"Subscriber.stale_after_s: expected a positive number, got {stale_after_s}")
        if isinstance(keep_recent, bool) or not isinstance(keep_recent, int) or keep_recent < 0:
            raise ValueError(f"Subscriber.keep_recent: expected a non-negative integer, got {keep_recent!r}")
        known = set(MESSAGE_TYPES.values())
        if accept is not None and (not accept or any(cls not in known for cls in accept)):
            raise ValueError(f"Subscriber.accept: expected message classes or None, got {accept!r}")
        self.endpoint = endpoint
        self.accept = None if accept is None else tuple(accept)
        self.stale_after_s = float(stale_after_s)
        self.limits = limits
        self._on_liveness = on_liveness
        self._on_restart = on_restart
        self._hwm, self._curve = hwm, curve
        self._socket: _Socket | None = None
        self._monitor = None
        self._open()
        self._cond = threading.Condition()
        self._latest = None
        self._recent: deque = deque(maxlen=keep_recent)
        self.data_arrived_at: float | None = None
        self.taken_arrived_at: float | None = None
        self._last_heartbeat: Heartbeat | None = None
        self._start = time.monotonic()
        self._last_rx: float | None = None
        self._stale = False
        self._beat_after_silence = False  # the next heartbeat is the first after a silence
        self.received = self.skipped = self.malformed = self.reconnects = 0
        self.last_malformed = ""
        self._warn_malformed = _WarningEvery()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"subscriber {endpoint}", daemon=True)
        self._thread.start()

    def _open(self) -> None:
        """Connect a new SUB socket, subscribed to everything, with a monitor of its disconnections."""
        self._socket = _Socket(zmq.SUB, self.endpoint, bind=False, limits=self.limits, curve=self._curve, hwm=self._hwm)
        self._socket.sock.setsockopt(zmq.SUBSCRIBE, b"")
        self._monitor = self._socket.sock.get_monitor_socket(zmq.EVENT_DISCONNECTED)

    def _close_socket(self) -> None:
        if self._monitor is not None:
            self._socket.sock.disable_monitor()
            self._monitor.close(linger=0)
            self._monitor = None
        self._socket.close()

    # -- consumer side ------------------------------------------------------

    def recv_latest(self, timeout_s: float):
        """The newest data message not yet returned, waiting up to ``timeout_s`` seconds.

        Returns a decoded message, or None on timeout (or once closed). Messages that
        arrived before it and were not taken are skipped, never queued.
        """
        deadline = time.monotonic() + timeout_s
        with self._cond:
            while self._latest is None:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self._stop.is_set():
                    return None
                self._cond.wait(remaining)
            msg, self._latest = self._latest, None
            self.taken_arrived_at = self.data_arrived_at
            self._recent.append(msg)  # a deque of maxlen 0 keeps nothing
        return msg

    def recent(self) -> list:
        """The last ``keep_recent`` data messages taken or skipped, oldest first (not the
        one still waiting for ``recv_latest``)."""
        with self._cond:
            return list(self._recent)

    def clear_recent(self) -> None:
        """Forget the messages ``recent()`` holds."""
        with self._cond:
            self._recent.clear()

    @property
    def age_s(self) -> float:
        """Seconds since the last message of any type; ``math.inf`` if none yet."""
        last = self._last_rx
        return math.inf if last is None else time.monotonic() - last

    @property
    def stale_limit_s(self) -> float:
        """Silence after which the publisher counts as gone: ``stale_after_s``, or three
        heartbeat periods if the publisher announced a longer period."""
        beat = self._last_heartbeat
        return self.stale_after_s if beat is None else max(self.stale_after_s, 3.0 * beat.period_s)

    @property
    def stale(self) -> bool:
        """True while the publisher counts as gone (no message for ``stale_limit_s``)."""
        return self._stale

    @property
    def last_heartbeat(self) -> Heartbeat | None:
        """The newest Heartbeat received, or None."""
        return self._last_heartbeat

    def close(self) -> None:
        """Stop the receiver thread and close the socket; a waiting ``recv_latest`` returns None."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        self._thread.join()
        self._close_socket()

    def __enter__(self) -> Subscriber:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- receiver thread ----------------------------------------------------

    def _run(self) -> None:
        tick_ms = int(1000 * min(0.05, self.stale_after_s / 4))  # how late a stale report may come
        while not self._stop.is_set():
            sock, monitor = self._socket.sock, self._monitor
            ready, _, _ = zmq.select([sock, monitor], [], [], tick_ms / 1000.0)
            if sock in ready:
                self._drain(sock)
            if monitor in ready:
                self._on_disconnected(monitor)
            self._check_stale()

    def _drain(self, sock: zmq.Socket) -> None:
        """Receive everything waiting; only the newest data message is kept."""
        while True:
            try:
                frames = _recv_message(sock, self.limits, zmq.NOBLOCK)
            except zmq.Again:
                return
            except ProtocolError as e:
                self._arrived()
                self._count_malformed(e)
                continue
            self._on_message(frames)

    def _on_disconnected(self, monitor) -> None:
        while monitor.poll(0):
            monitor.recv_multipart()  # the event: ZMQ_EVENT_DISCONNECTED, the only one monitored
        # Whether the peer went away (libzmq would reconnect) or was dropped for an
        # oversize frame (libzmq would not), a new socket reconnects in both cases.
        self._close_socket()
        self._open()
        self.reconnects += 1
        log.info("%s: connection to the publisher lost; reconnecting (%d so far)", self.endpoint, self.reconnects)

    def _arrived(self) -> float:
        """Note a message's arrival (proof that the publisher lives); returns the time."""
        now = time.monotonic()
        gap = now - (self._last_rx if self._last_rx is not None else self._start)
        self._last_rx = now
        self.received += 1
        if self._stale:
            self._stale = False
            self._beat_after_silence = True
            log.info("%s: receiving again after %.1f s of silence", self.endpoint, gap)
            self._notify(self._on_liveness, True, gap)
        return now

    def _on_message(self, frames: list) -> None:
        now = self._arrived()
        try:
            cls = peek_type(frames, self.limits)
            if cls is not Heartbeat and self.accept is not None and cls not in self.accept:
                served = ", ".join(c.__name__ for c in self.accept)
                raise ProtocolError(f"a {cls.__name__} is not carried here; expected {served} or Heartbeat")
            msg = decode(frames, self.limits)
        except ProtocolError as e:
            self._count_malformed(e)
            return
        if cls is Heartbeat:
            self._on_heartbeat(msg)
            return
        with self._cond:
            if self._latest is not None:
                self.skipped += 1
                self._recent.append(self._latest)
            self._latest = msg
            self.data_arrived_at = now
            self._cond.notify_all()

    def _on_heartbeat(self, beat: Heartbeat) -> None:
        previous, self._last_heartbeat = self._last_heartbeat, beat
        after_silence, self._beat_after_silence = self._beat_after_silence, False
        if previous is not None and (beat.source != previous.source or beat.seq < previous.seq):
            log.info("%s: publisher %r restarted (heartbeat seq %d after %d)", self.endpoint, beat.source, beat.seq, previous.seq)
            if not after_silence:
                self._notify(self._on_restart, previous, beat)

    def _check_stale(self) -> None:
        age = time.monotonic() - (self._last_rx if self._last_rx is not None else self._start)
        if self._stale or age <= self.stale_limit_s:
            return
        if self._socket.sock.poll(0, zmq.POLLIN):
            # Messages wait unread: this thread was starved of CPU, the publisher was not silent.
            return
        self._stale = True
        name = f" {self._last_heartbeat.source!r}" if self._last_heartbeat else ""
        log.warning("%s: no message from publisher%s for %.1f s; gone?", self.endpoint, name, age)
        self._notify(self._on_liveness, False, age)

    def _notify(self, callback, *args) -> None:
        if callback is None:
            return
        try:
            callback(*args)
        except Exception:  # a faulty callback must not kill the receiver thread
            log.exception("%s: subscriber callback failed", self.endpoint)

    def _count_malformed(self, error: ProtocolError) -> None:
        with self._cond:
            self.malformed += 1
            self.last_malformed = _one_line(str(error))
        self._warn_malformed("%s: dropped a malformed message: %s", self.endpoint, error)


class RequestClient:
    """REQ client with a timeout per attempt and a bounded number of attempts.

    endpoint : the server's endpoint, e.g. ``ipc.endpoints.PLANNER``
    timeout_s : seconds to wait for a reply per attempt
    attempts : sends before giving up; the requests of this protocol are idempotent,
        so resending after a lost reply is safe
    limits, curve : decoder caps for replies, CurveClient or None

    After a timeout the REQ socket is closed and a new one opened (REQ cannot send
    again before it has a reply); a late reply to the old socket is discarded.
    """

    def __init__(
        self,
        endpoint: str,
        *,
        timeout_s: float = REQUEST_TIMEOUT_S,
        attempts: int = REQUEST_ATTEMPTS,
        limits: Limits = DEFAULT_LIMITS,
        curve: CurveClient | None = None,
    ):
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"RequestClient.timeout_s: expected a positive number, got {timeout_s}")
        if isinstance(attempts, bool) or not isinstance(attempts, int) or attempts < 1:
            raise ValueError(f"RequestClient.attempts: expected a positive integer, got {attempts!r}")
        self.endpoint, self.timeout_s, self.attempts = endpoint, float(timeout_s), attempts
        self.limits, self.curve = limits, curve
        self._socket: _Socket | None = None
        self._open()  # connect now so that a bad endpoint fails here, not at the first request

    def _open(self) -> _Socket:
        self._socket = _Socket(zmq.REQ, self.endpoint, bind=False, limits=self.limits, curve=self.curve)
        return self._socket

    def request(self, msg, *, timeout_s: float | None = None):
        """Send ``msg`` and return the decoded reply.

        timeout_s : per-attempt timeout for this call; None uses the client's.
        Raises RequestTimeout after ``attempts`` attempts without a reply, RemoteError
        when the reply is an ErrorReply, ProtocolError when ``msg`` cannot be encoded or
        the reply cannot be decoded.
        """
        frames = encode(msg)
        timeout_ms = int(1000 * (self.timeout_s if timeout_s is None else timeout_s))
        for attempt in range(1, self.attempts + 1):
            sock = (self._socket or self._open()).sock
            sock.setsockopt(zmq.SNDTIMEO, timeout_ms)
            try:
                sock.send_multipart(frames, copy=False)
                if sock.poll(timeout_ms, zmq.POLLIN):
                    reply = decode(_recv_message(sock, self.limits), self.limits)
                    if isinstance(reply, ErrorReply):
                        raise RemoteError(reply)
                    return reply
            except zmq.Again:
                pass  # could not even queue the request: same as no reply
            log.warning(
                "%s: no reply to %s within %d ms (attempt %d of %d)", self.endpoint, type(msg).__name__, timeout_ms, attempt,
                self.attempts
            )
            self._socket.close()
            self._socket = None
        raise RequestTimeout(f"{self.endpoint}: no reply to {type(msg).__name__} after {self.attempts} attempts "
                             f"of {timeout_ms} ms")

    def close(self) -> None:
        if self._socket is not None:
            self._socket.close()
            self._socket = None

    def __enter__(self) -> RequestClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class ReplyServer:
    """REP server that binds ``endpoint`` and answers each request with one reply.

    handlers : request class -> callable(request) -> reply message. A request of another
        type is answered ErrorReply("unsupported"); one that cannot be decoded,
        ErrorReply("protocol") (logged at most once a second); a handler raising ValueError,
        ErrorReply("invalid");
        raising anything else (logged with its traceback), ErrorReply("internal").
        A handler may also return an ErrorReply itself (e.g. "not_ready").
    limits, curve : decoder caps for requests, CurveServer or None

    Serve from one thread: ``serve_once`` inside a service's own loop, or
    ``serve_forever`` in a thread of its own.
    """

    def __init__(
        self,
        endpoint: str,
        handlers: Mapping[type, Callable],
        *,
        limits: Limits = DEFAULT_LIMITS,
        curve: CurveServer | None = None,
    ):
        known = set(MESSAGE_TYPES.values())
        if not handlers or any(cls not in known or not callable(fn) for cls, fn in handlers.items()):
            raise ValueError("ReplyServer.handlers: expected a non-empty mapping from message class to callable")
        self.handlers = dict(handlers)
        self.limits = limits
        self._socket = _Socket(zmq.REP, endpoint, bind=True, limits=limits, curve=curve)
        self._warn_malformed = _WarningEvery()
        self.endpoint = self._socket.endpoint
        log.info("%s: serving %s", self.endpoint, ", ".join(cls.__name__ for cls in self.handlers))

    def serve_once(self, timeout_s: float = 0.0) -> bool:
        """Answer at most one request, waiting up to ``timeout_s``; True if one was answered."""
        sock = self._socket.sock
        if sock is None:
            raise ValueError(f"{self.endpoint}: server is closed")
        if not sock.poll(int(1000 * timeout_s), zmq.POLLIN):
            return False
        try:
            request = decode(_recv_message(sock, self.limits), self.limits)
        except ProtocolError as e:
            self._warn_malformed("%s: malformed request: %s", self.endpoint, e)
            reply = ErrorReply("protocol", str(e), e.request_id)
        else:
            reply = self._handle(request)
        try:
            frames = encode(reply)
        except ProtocolError as e:
            log.error("%s: reply %s cannot be encoded: %s", self.endpoint, type(reply).__name__, e)
            why = _one_line(f"reply could not be encoded: {e}")
            frames = encode(ErrorReply("internal", why, getattr(reply, "request_id", 0)))
        sock.send_multipart(frames, copy=False)
        return True

    def _handle(self, request):
        request_id = getattr(request, "request_id", 0)
        handler = self.handlers.get(type(request))
        if handler is None:
            served = ", ".join(cls.__name__ for cls in self.handlers)
            return ErrorReply("unsupported", f"{type(request).__name__} is not served here; expected one of {served}", request_id)
        try:
            reply = handler(request)
        except ValueError as e:
            return ErrorReply("invalid", _one_line(str(e)) or type(e).__name__, request_id)
        except Exception as e:  # any handler failure is answered, and the server keeps serving
            log.exception("%s: handler for %s failed", self.endpoint, type(request).__name__)
            return ErrorReply("internal", _one_line(f"{type(e).__name__}: {e}"), request_id)
        if type(reply) not in MESSAGE_TYPES.values():
            log.error("%s: handler for %s returned %s", self.endpoint, type(request).__name__, type(reply).__name__)
            return ErrorReply("internal", f"handler returned {type(reply).__name__}, not a message", request_id)
        return reply

    def serve_forever(self, stop: threading.Event, poll_s: float = 0.1) -> None:
        """Serve until ``stop`` is set, checking it every ``poll_s`` seconds."""
        while not stop.is_set():
            self.serve_once(poll_s)

    def close(self) -> None:
        self._socket.close()

    def __enter__(self) -> ReplyServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
