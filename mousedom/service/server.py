"""The Unix-socket publisher: listening socket, clients, bounded queues, permissions.

The server never blocks the fusion, and no client starves another (docs/protocol.md,
"Limits").  Every socket is non-blocking.  What a client cannot take right now waits: the
lines it is owed (VERSION, SOURCE, replies, ERROR) in order, at most ``queue_lines`` of
them, and of the POSEs only the latest, which replaces an older one still waiting.  So after
any stall (the daemon's or the client's) a reading client gets the freshest pose next, not
a backlog.  A client is dropped only for not reading while the daemon runs: its owed lines
overflow, or its output has waited ``idle_timeout_s`` of the daemon's running time (a
stall of the daemon itself does not count against anyone): what it sends does not excuse
not reading.

The work one client can cause per loop iteration is bounded (``Budget``): a few accepts
per wake-up, one read of ``READ_BYTES`` and ``LINES_PER_TURN`` lines per client (the rest
waits for the next iteration), and lines that carry nothing (blank, or answered with an
ERROR) draw on a small allowance that refills with time; a client that exhausts it is
dropped.  Commands
are parsed by ``mousedom.service.protocol``; the ones that move the pose are allowed only to
the uids and gids of ``server.control_uids/control_gids`` (and the daemon's own uid), read from the
peer with SO_PEERCRED.  The daemon owns the selector and calls ``Server.handle_event`` for
the keys it registered; the daemon applies commands through the ``on_command`` callback.
"""

from __future__ import annotations

import errno
import logging
import math
import os
import resource
import select
import selectors
import socket
import struct
from collections import deque
from collections.abc import Callable
from typing import Any

from mousedom.config import ServerConfig
from mousedom.service import socketfile
from mousedom.service.protocol import (
    POSE_MOVING,
    Command,
    LineBuffer,
    ProtocolError,
    TooLong,
    encode,
    error_message,
    parse_command,
)

log = logging.getLogger(__name__)

# Small kernel send buffers make a stalled client show up in its queue within a second or
# two instead of after the kernel has swallowed minutes of poses.
SNDBUF = 32 * 1024
# What one client may cause per loop iteration (see the module docstring).
ACCEPTS_PER_TURN = 4
READ_BYTES = 4096
LINES_PER_TURN = 16
# Lines that carry nothing: a burst of this many, then this many a second.
JUNK_BURST = 64
JUNK_PER_S = 8.0
# A gap between two loop iterations longer than this is the daemon's own stall (SIGSTOP, a
# VM pause, swapping): only this much of it counts as running time.
MAX_TICK_S = 1.5  # the loop wakes at least once a second (SOURCE), whatever the rate
# Out of descriptors: the listener rests this long (or until a client leaves).
ACCEPT_PAUSE_S = 0.5
# Refusals for the client limit are logged at most once in this much running time, each
# line with the number refused since the last (a flood of 3,000 connects wrote 392 lines).
REFUSED_LOG_S = 10.0
_OUT_OF_RESOURCES = (errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM)


class Client:
    """One connected peer: its credentials, input framing, output queue and POSE rate."""

    def __init__(self, sock: socket.socket, settings: ServerConfig, control: bool) -> None:
        self.sock = sock
        self.fd = sock.fileno()
        self.pid, self.uid, self.gid = peer_credentials(sock)
        self.control = control
        self.rx = LineBuffer(settings.max_line)
        self.lines: deque[bytes | TooLong] = deque()  # read, not yet answered (LINES_PER_TURN)
        self.queue: deque[bytes] = deque()  # lines owed, in order
        self.states: dict[str, bytes] = {}  # the latest SOURCE per sensor, not yet sent
        self.pose: bytes | None = None  # the latest POSE not yet handed to the kernel
        self.queue_limit = settings.queue_lines
        self.partial = b""  # the unsent tail of the line(s) being written
        self.waiting_since: float | None = None  # running time since output has waited
        self.junk = float(JUNK_BURST)  # allowance for lines that carry nothing
        self.junk_t = 0.0  # running time of the allowance's last refill
        self.denied_logged = False  # a reset/fix refused for want of control was logged
        self.want_write = False  # registered for EVENT_WRITE (a tail is waiting)
        # False once the peer has shut its sending side (EOF): it may still be reading,
        # as `echo status | nc -U` is (a client is dropped only for not reading).
        self.reading = True
        self.closing = False  # half-closed at rate 0: it goes once its owed lines are out
        self.held = False  # lines read wait for their answers: its input is not watched
        self.handler: Callable[[int], None] | None = None  # its selector callback
        self.period = 0.0  # seconds between POSEs for this client; 0: every pose
        self.paused = False  # rate 0: no POSE at all
        self.next_t: float | None = None
        self.lines_out = 0
        # The last VERSION it was sent (set by the daemon's on_connect): a reload that
        # changes what it says sends a fresh one (reload.py)
        self.version: dict[str, Any] | None = None

    def __repr__(self) -> str:
        return f"client fd={self.fd} pid={self.pid} uid={self.uid}"

    def wants_pose(self, t: float, tolerance: float) -> bool:
        """Decimate POSE to this client's own rate, keeping a steady phase."""
        if self.paused:
            return False
        if self.period <= 0:
            return True
        if self.next_t is None or t >= self.next_t - tolerance:
            base = t if self.next_t is None else self.next_t
            self.next_t = base + self.period
            if self.next_t < t:  # fell far behind (paused rate change): restart the phase
                self.next_t = t + self.period
            return True
        return False

    def set_rate(self, hz: float) -> None:
        self.paused = hz == 0
        self.period = 1.0 / hz if hz > 0 else 0.0
        self.next_t = None


def peer_credentials(sock: socket.socket) -> tuple[int, int, int]:
    """(pid, uid, gid) of the process at the other end of a Unix socket (SO_PEERCRED)."""
    fmt = "3i"
    raw = sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize(fmt))
    return struct.unpack(fmt, raw)


class Server:
    """Listening socket plus clients, driven by the daemon's selector."""

    def __init__(
        self,
        path: str,
        settings: ServerConfig,
        selector: selectors.BaseSelector,
        on_command: Callable[[Client, Command], list[dict[str, Any]]],
        on_connect: Callable[[Client], list[dict[str, Any]]],
    ) -> None:
        self.path = path
        self.settings = settings
        self.selector = selector
        self.on_command = on_command
        self.on_connect = on_connect
        self.clients: dict[int, Client] = {}
        self.listener: socket.socket | None = None
        self.access: socketfile.Access | None = None  # the socket file's mode and group
        self.dropped = 0  # clients dropped for not reading (owed lines overflowing, idle)
        self.refused = 0  # clients refused for the client limit
        self._refused_logged = (0, -math.inf)  # self.refused and self.running at the last line
        # The daemon's running time: wall time with its own stalls cut to MAX_TICK_S, so a
        # paused daemon never blames its clients for what it did not send.
        self.running = 0.0
        self._last_tick: float | None = None
        self._next_check = 0.0
        # Clients with read lines still to answer, in turn (a dict: ordered, and a client
        # served goes to the end)
        self.backlog: dict[Client, None] = {}
        # Set by the daemon around a wake's client work: whether its time is spent
        self.over_budget: Callable[[], bool] = no_budget
        # Accepting paused for want of descriptors: (running time to resume, clients then)
        self._accept_resume: tuple[float, int] | None = None
        self._accept_failed: OSError | None = None  # the episode's error (said once)

    # ------------------------------------------------------------------ lifecycle

    def open(self) -> None:
        sock, self.access = socketfile.listen(self.path, self.settings)
        self.listener = sock
        self.selector.register(sock, selectors.EVENT_READ, self._accept)
        self._check_room()

    def _check_room(self) -> None:
        """Say at the start (and at a reload) where ``max_clients`` is more connections than
        this process may open descriptors for: the rest would wait (``_pause_accepting``)."""
        soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
        try:
            in_use = len(os.listdir("/proc/self/fd"))
        except OSError:
            return
        room = soft - in_use
        if soft != resource.RLIM_INFINITY and self.settings.max_clients > room:
            log.warning("server.max_clients is %d, but this process may open %d more files "
                        "(limit %d): clients beyond about %d wait; raise LimitNOFILE= in the "
                        "unit or lower max_clients", self.settings.max_clients, room, soft,
                        room)  # fmt: skip

    def refuse_if_taken(self) -> None:
        """UserError if another daemon listens at the path already (socketfile.py)."""
        socketfile.refuse_if_taken(self.path)

    def close(self) -> None:
        for client in list(self.clients.values()):
            self._flush(client)
            self.drop(client, None)
        if self.listener is not None:
            if self._accept_resume is None:
                self.selector.unregister(self.listener)
            self.listener.close()
            self.listener = None
            if self.access is not None:
                socketfile.remove_own(self.access)

    def apply_settings(self, settings: ServerConfig) -> None:
        """New limits after a reload, and the socket file's group and mode as at start
        (``socketfile.reapply``); the socket path and existing clients stay."""
        self.settings = settings
        if self.access is not None:  # (open: the socket file is there)
            self.access = socketfile.reapply(self.access, settings)
            self._check_room()
        for c in self.clients.values():
            c.queue_limit = settings.queue_lines
            c.rx.max_line = settings.max_line
            c.control = self.may_control(c.uid, c.gid)

    def may_control(self, uid: int, gid: int) -> bool:
        s = self.settings
        return uid in s.control_uids or gid in s.control_gids or uid == os.getuid()

    # ------------------------------------------------------------------ events

    def _accept(self, events: int) -> None:
        assert self.listener is not None
        for _ in range(ACCEPTS_PER_TURN):  # the rest wait in the listen backlog
            try:
                sock, _ = self.listener.accept()
            except (BlockingIOError, InterruptedError):
                return
            except OSError as e:
                if e.errno in _OUT_OF_RESOURCES:
                    self._pause_accepting(e)
                elif e.errno not in (errno.ECONNABORTED, errno.EPROTO):  # (the peer's doing)
                    log.warning("accept failed: %s", e)
                return
            self._accept_failed = None  # (a pause's episode is over)
            sock.setblocking(False)
            try:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SNDBUF)
            except OSError:
                pass
            _, uid, gid = peer_credentials(sock)
            client = Client(sock, self.settings, self.may_control(uid, gid))
            if len(self.clients) >= self.settings.max_clients:
                self.refused += 1
                self._log_refused(client)
                try:
                    sock.send(encode(error_message("too many clients; try again later")))
                except OSError:
                    pass
                sock.close()
                continue
            client.junk_t = self.running
            self.clients[client.fd] = client
            client.handler = self._make_handler(client)
            self.selector.register(sock, selectors.EVENT_READ, client.handler)
            log.debug("connected %r (control=%s)", client, client.control)
            try:
                for msg in self.on_connect(client):
                    self.send(client, encode(msg))
            except Exception as e:  # noqa: BLE001 - as in handle(): only this client goes
                self._fail(client, e)

    def _log_refused(self, client: Client) -> None:
        logged, at = self._refused_logged
        if self.running < at + REFUSED_LOG_S:
            return
        since = self.refused - logged - 1
        log.warning("refusing %r: already %d clients (server.max_clients)%s", client,
                    len(self.clients), f"; {since} more refused since the last such line"
                    if since else "")  # fmt: skip
        self._refused_logged = (self.refused, self.running)

    def _pause_accepting(self, error: OSError) -> None:
        """Out of descriptors (or memory): the listener stays readable, and accepting at
        every wake spun the loop at a full core and logged 65,000 lines a second.  The
        listener is not watched for ``ACCEPT_PAUSE_S`` of running time (or until a client
        leaves); new connections wait in the kernel's backlog.  Said once an episode."""
        assert self.listener is not None
        self.selector.unregister(self.listener)
        self._accept_resume = (self.running + ACCEPT_PAUSE_S, len(self.clients))
        if self._accept_failed is None:
            soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
            log.warning("cannot accept connections: %s (%d clients; this process may open %d "
                        "files): new ones wait until a client leaves (server.max_clients %d; "
                        "LimitNOFILE= in the unit)", error.strerror, len(self.clients), soft,
                        self.settings.max_clients)  # fmt: skip
        self._accept_failed = error

    def _resume_accepting(self) -> None:
        resume = self._accept_resume
        if resume is None or self.listener is None:
            return
        until, clients = resume
        if self.running >= until or len(self.clients) < clients:
            self._accept_resume = None
            self.selector.register(self.listener, selectors.EVENT_READ, self._accept)

    def _make_handler(self, client: Client) -> Callable[[int], None]:
        def handle(events: int) -> None:
            try:
                if events & selectors.EVENT_WRITE and self.alive(client):
                    self._flush(client)
                if events & selectors.EVENT_READ and self.alive(client):
                    self._read(client)
            except Exception as e:  # noqa: BLE001 - one client must never stop the daemon
                self._fail(client, e)

        return handle

    def _fail(self, client: Client, error: Exception) -> None:
        """What a client's line or connection broke is logged, and only that client goes."""
        log.error("%r: %s: %s (dropping this client)", client, type(error).__name__, error,
                  exc_info=error)  # fmt: skip
        self.drop(client, f"internal error: {type(error).__name__}")

    def _read(self, client: Client) -> None:
        if client.lines:
            self._answer_some(client)  # its earlier lines first; the socket waits
            return
        try:
            data = client.sock.recv(READ_BYTES)
        except (BlockingIOError, InterruptedError):
            return
        except OSError as e:
            # A reset is a peer that closed with lines unread (a probe, a client that quit
            # mid-stream): a disconnect, as on the write side, not a warning for each.
            self.drop(client, None if e.errno == errno.ECONNRESET else f"read error: {e}")
            return
        if not data:
            self._end_of_input(client)
            return
        client.lines.extend(client.rx.feed(data))
        self._answer_some(client)

    def _answer_some(self, client: Client) -> None:
        """Answer up to LINES_PER_TURN of a client's lines while the wake's budget lasts
        and the client takes its answers; the rest wait in ``backlog``.

        Back-pressure: while half its owed queue is full the client's lines wait (and,
        once they are all answered, its socket is not read: the kernel's buffers fill and
        its sends block).  Answering regardless dropped a client that read as fast as it
        could but had sent thousands of commands at once ("queue full").  A client that
        does not read at all is dropped by ``idle_timeout_s``."""
        lines = client.lines
        for _ in range(min(len(lines), LINES_PER_TURN)):
            if not self.alive(client):
                return
            if len(client.queue) >= client.queue_limit // 2 or self.over_budget():
                break
            for msg in self._answer(client, lines.popleft()):
                self.send(client, encode(msg))
        self.backlog.pop(client, None)
        if not self.alive(client):
            return
        held = bool(lines)
        if held:
            self.backlog[client] = None  # (at the end: the others' turn first)
        if held != client.held:  # its socket is not read while lines wait (no spin)
            client.held = held
            self._register(client)

    def backlog_ready(self) -> bool:
        """Whether a client has lines waiting that it could be answered now (not held back
        by its own full queue): the loop then does not sleep before its next turn."""
        return any(len(c.queue) < c.queue_limit // 2 for c in self.backlog)

    def serve_backlog(self) -> None:
        """A turn for each client with lines read but not yet answered, in order, while the
        wake's budget lasts (the daemon calls this once per loop iteration: such a client's
        socket may not wake it again)."""
        for client in list(self.backlog):
            if self.over_budget():
                return
            if not self.alive(client):
                self.backlog.pop(client, None)
                continue
            try:
                self._answer_some(client)
            except Exception as e:  # noqa: BLE001 - as in handle(): only this client goes
                self._fail(client, e)

    def _junk(self, client: Client) -> None:
        """A line that carried nothing: it draws on the client's allowance."""
        c = client
        c.junk = min(JUNK_BURST, c.junk + (self.running - c.junk_t) * JUNK_PER_S) - 1.0
        c.junk_t = self.running
        if c.junk < 0:
            self.dropped += 1
            self.drop(c, f"sends lines that carry nothing (blank or bad) faster than "
                         f"{JUNK_PER_S:g} a second")  # fmt: skip

    def _answer(self, client: Client, line: bytes | TooLong) -> list[dict[str, Any]]:
        if isinstance(line, TooLong):
            self._junk(client)
            return [error_message(f"line too long ({line.size} > {client.rx.max_line} bytes)")]
        if not line.strip():
            self._junk(client)
            return []
        try:
            cmd = parse_command(line)
        except ProtocolError as e:
            self._junk(client)
            return [error_message(str(e), e.id)]
        if cmd.name in POSE_MOVING and not client.control:
            # A refused line carries nothing either: it draws on the allowance, and a
            # client that floods them is dropped (24,550 in 5 s were each answered and
            # logged); the journal hears of the first only.
            if not client.denied_logged:
                client.denied_logged = True
                log.warning("%r may not %s the pose (server.control_uids/gids); further "
                            "refusals to it are not logged", client, cmd.name)  # fmt: skip
            self._junk(client)
            return [
                error_message(
                    f"{cmd.name}: not allowed for uid {client.uid} gid {client.gid} "
                    "(see server.control_uids and control_gids)",
                    cmd.id,
                )
            ]
        return self.on_command(client, cmd)

    # ------------------------------------------------------------------ output

    def send(self, client: Client, line: bytes) -> None:
        """Queue one line the client is owed; drop the client when its owed lines overflow
        (it has not read for that long)."""
        if not self.alive(client) or self._sent_now(client, line):
            return
        if len(client.queue) >= client.queue_limit:
            self.dropped += 1
            self.drop(client, f"queue full ({client.queue_limit} lines): client not reading")
            return
        # What waits to be replaced was made before this line: it goes before it, in order
        # (a reply to a reset must not be followed by the pose from before the reset).
        if client.states:
            client.queue.extend(client.states.values())
            client.states = {}
        if client.pose is not None:
            client.queue.append(client.pose)
            client.pose = None
        client.queue.append(line)

    def send_pose(self, client: Client, line: bytes) -> None:
        """A POSE: sent now if nothing waits, else it replaces the POSE waiting (if any)."""
        if not self.alive(client) or self._sent_now(client, line):
            return
        client.pose = line

    def _sent_now(self, client: Client, line: bytes) -> bool:
        """Nothing waiting (the usual case): the line goes out now, without the queue."""
        if client.queue or client.partial or client.pose is not None or client.states:
            return False
        client.partial = line
        client.lines_out += 1
        self._flush(client)
        return True

    def broadcast_state(self, key: str, line: bytes) -> None:
        """A state line (a sensor's SOURCE) to every client: sent now where nothing waits,
        else it replaces the line of the same ``key`` still waiting: a client that lags
        gets each sensor's latest state, not a backlog of them."""
        for client in list(self.clients.values()):
            if self.alive(client) and not self._sent_now(client, line):
                client.states[key] = line
                self._want_write(client, True)

    def broadcast(self, line: bytes) -> None:
        for client in list(self.clients.values()):
            self.send(client, line)

    def broadcast_pose(self, t: float, line: bytes, tolerance: float) -> int:
        """Send a POSE line to the clients whose own rate wants one at time ``t``."""
        n = 0
        for client in list(self.clients.values()):
            if client.wants_pose(t, tolerance):
                self.send_pose(client, line)
                n += 1
        return n

    def _flush(self, client: Client) -> None:
        sock = client.sock
        while client.partial or client.queue or client.pose is not None or client.states:
            if not client.partial:
                # Several lines per send: fewer syscalls when a client lags a little.
                # The lines owed go first, then the sensors' latest states, then the
                # latest POSE.
                chunk: list[bytes] = []
                while client.queue and len(chunk) < 64:
                    chunk.append(client.queue.popleft())
                if not client.queue and client.states:
                    chunk += client.states.values()
                    client.states = {}
                if not client.queue and client.pose is not None:
                    chunk.append(client.pose)
                    client.pose = None
                client.partial = b"".join(chunk)
                client.lines_out += len(chunk)
            try:
                n = sock.send(client.partial)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as e:
                quiet = e.errno in (errno.EPIPE, errno.ECONNRESET)
                self.drop(client, None if quiet else f"write error: {e}")
                return
            client.partial = client.partial[n:]
            client.waiting_since = None  # it takes what it is sent
        waiting = _waiting(client)
        if client.closing and _done(client):
            self.drop(client, None)  # (all it was owed is out, and nothing is to come)
            return
        if waiting and client.waiting_since is None:
            client.waiting_since = self.running
        self._want_write(client, waiting)

    def tick(self, now: float) -> None:
        """Once per loop iteration: advance the running time (a stall of the daemon counts
        for at most MAX_TICK_S) and, a few times a second, drop clients whose output has
        waited ``idle_timeout_s`` of it (their socket took nothing), and half-closed
        clients that have since closed."""
        if self._last_tick is not None:
            self.running += min(max(now - self._last_tick, 0.0), MAX_TICK_S)
        self._last_tick = now
        if self._accept_resume is not None:
            self._resume_accepting()
        if self.running < self._next_check:
            return
        self._next_check = self.running + 0.1
        limit = self.settings.idle_timeout_s
        for client in list(self.clients.values()):
            since = client.waiting_since
            if since is not None and self.running - since > limit:
                self.dropped += 1
                self.drop(client, f"idle: took nothing for {limit:g} s")
            elif not client.reading and _hung_up(client.sock):
                # half-closed, then closed: its socket is no longer watched, and nothing
                # may be sent to it for long (an idle daemon, a slow rate) to find out
                self.drop(client, None)

    def _end_of_input(self, client: Client) -> None:
        """The peer sent EOF: it closed, or only shut its sending side.  Closed (a Unix
        socket then polls as hung up: both directions shut), it goes.  Paused (rate 0: no
        POSE would reach it), it goes once it has what it is owed (dropped at once, it lost
        the replies its own commands had not yet been sent); else it stays while it reads."""
        if _hung_up(client.sock):
            self.drop(client, None)
            return
        client.reading = False  # (EOF stays readable: the socket is no longer read)
        last = client.rx.finish()  # a last command without its newline
        if last:
            client.lines.extend(last)
            self._answer_some(client)
            if not self.alive(client):
                return
        if client.paused:
            client.closing = True
            if _done(client):
                self.drop(client, None)
                return
        self._register(client)

    def _want_write(self, client: Client, want: bool) -> None:
        if want == client.want_write:
            return
        client.want_write = want
        self._register(client)

    def _register(self, client: Client) -> None:
        """The selector watches what the client needs: its input until EOF, its socket's
        room while a tail waits; neither (a half-closed client, all sent): not at all."""
        events = (selectors.EVENT_READ if client.reading and not client.held else 0) | (
            selectors.EVENT_WRITE if client.want_write else 0
        )
        registered = client.sock in self.selector.get_map()
        if not events:
            if registered:
                self.selector.unregister(client.sock)
        elif registered:
            self.selector.modify(client.sock, events, client.handler)
        else:
            self.selector.register(client.sock, events, client.handler)

    def alive(self, client: Client) -> bool:
        """Whether this client is still connected.  By identity, not by descriptor: a client
        dropped earlier in a wake frees its fd, which a client accepted later may reuse."""
        return self.clients.get(client.fd) is client

    def drop(self, client: Client, reason: str | None) -> None:
        if not self.alive(client):
            return
        del self.clients[client.fd]
        self.backlog.pop(client, None)
        if reason:
            log.warning("dropping %r: %s", client, reason)
        else:
            log.debug("disconnected %r", client)
        try:
            self.selector.unregister(client.sock)
        except (KeyError, ValueError):
            pass
        client.sock.close()


def _waiting(client: Client) -> bool:
    """Whether anything waits to be sent to the client."""
    return bool(client.partial or client.queue or client.pose is not None or client.states)


def _done(client: Client) -> bool:
    """Whether nothing waits to be sent to the client and none of its lines waits to be
    answered: a half-closed client at rate 0 goes then."""
    return not _waiting(client) and not client.lines


def no_budget() -> bool:
    return False


def _hung_up(sock: socket.socket) -> bool:
    """Whether the peer closed (POLLHUP), as opposed to shutting its sending side only
    (POLLRDHUP): Linux's Unix stream sockets tell the two apart."""
    p = select.poll()
    p.register(sock, select.POLLOUT)
    return any(ev & (select.POLLHUP | select.POLLERR) for _, ev in p.poll(0))
