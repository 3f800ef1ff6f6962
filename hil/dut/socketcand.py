"""A socketcand-protocol server: an in-process python-can bus reachable from other processes.

``hil dut serve`` puts the virtual controller on a python-can ``virtual`` channel and exposes
that bus with the socketcand raw-mode protocol (https://github.com/linux-can/socketcand), so
python-can's own ``socketcand`` interface is the client, and the same client reaches a real
socketcand daemon on a bench PC with a real adapter:

    can.Bus(interface="socketcand", channel="can0", host="127.0.0.1", port=PORT)

The server speaks only what a raw-mode client needs (``< hi >``, ``< open BUS >``,
``< rawmode >``, ``< send ID DLC B.. >``, ``< echo >``; frames go out as
``< frame ID SEC.USEC HEX >``) and serves nothing else: no files, no HTTP. It is hardened
against the clients it may meet on a shared port:

- a connection cap (``max_clients``); the next client is told ``< error too many clients >``;
- the handshake must finish within ``handshake_timeout_s``; a command once begun must end
  within ``partial_timeout_s`` and ``max_command_bytes`` (slow-loris);
- a raw-mode client that sends nothing for ``idle_timeout_s`` is closed (TCP keepalive also on);
- every client has a bounded frame queue: a client that does not read loses its oldest frames,
  as a CAN controller overruns, and one that reads nothing for ``idle_timeout_s`` is closed;
- a client that leaves, or is killed, is forgotten at once (its queue goes with it);
- a client that sends faster than the device takes frames overruns it, as on a real bus: beyond
  ``max_backlog_frames`` waiting for the device, the oldest is dropped (a CAN controller's receive
  FIFO overruns; a real socketcand drops the frame the kernel refuses). Held back instead, a
  burst of 10,000 frames delayed the next request's answer by seconds, past any SDO client's
  timeout. The operator is told (one line, naming the client and the count);
- every client the server closes, or that is lost, is one WARNING line with its address and why.
"""

from __future__ import annotations

import asyncio
import collections
import logging
import queue
import re
import socket
import threading
import time
from dataclasses import dataclass, field

import can

from bldc.contract import MAX_ADC_SAMPLES

from .tcp import close_handlers

log = logging.getLogger(__name__)

#: read at once from a client (and held by its stream before reading pauses: twice this): some
#: 1,700 commands, so a burst is read and split in few steps
_READ_BYTES = 65536
#: a command: from a '<' to the next '>'
_COMMAND = re.compile(rb"<([^>]*)>")
#: the shape of a send; well_formed_send checks the rest
_SEND = re.compile(rb"\s*send\s+([0-9A-Fa-f]{1,8})\s+([0-8])((?:\s+[0-9A-Fa-f]{1,2})*)\s*")


@dataclass(frozen=True)
class SocketcandLimits:
    max_clients: int = 16
    queue_frames: int = 4096            #: per client; the oldest is dropped beyond this (an overrun)
    handshake_timeout_s: float = 5.0    #: hi -> open -> rawmode
    partial_timeout_s: float = 5.0      #: a command begun must end within this
    idle_timeout_s: float = 300.0       #: raw mode: no command, or nothing read, for this long closes
    max_command_bytes: int = 128        #: '< send 1FFFFFFF 8 ff ff ff ff ff ff ff ff >' is 41
    #: frames the device has not yet taken; the oldest is dropped beyond this (a receive FIFO that
    #: holds one whole edge message of the longest window, bldc.contract.MAX_ADC_SAMPLES conversions,
    #: three accumulators and the header: 256 frames, four of the usual <= 56-frame ones; a larger
    #: FIFO only lets a burst delay the next request longer: tests/test_serve_hardening.py)
    max_backlog_frames: int = MAX_ADC_SAMPLES + 4
    overrun_log_interval_s: float = 10.0  #: a client that keeps overrunning the device: one line this often


class ProtocolError(Exception):
    """The client broke the protocol; it is told so (one line) and disconnected."""


@dataclass(eq=False)
class _Client:
    writer: asyncio.StreamWriter
    queue: collections.deque
    peer: str = "?"
    ready: asyncio.Event = field(default_factory=asyncio.Event)
    dropped: int = 0   #: frames to this client lost because it read too slowly
    overrun: int = 0   #: frames from this client the device never saw (sent too fast), not yet logged
    overrun_logged_at: float = float("-inf")

    def put(self, line: bytes) -> None:
        if len(self.queue) == self.queue.maxlen:
            self.dropped += 1
        self.queue.append(line)
        self.ready.set()


def frame_line(msg: can.Message) -> bytes:
    """A received frame as socketcand sends it: 3 hex digits for a standard id, 8 for extended."""
    can_id = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
    return f"< frame {can_id} {msg.timestamp:.6f} {bytes(msg.data).hex().upper()} >".encode("ascii")


def parse_send(words: list[str]) -> can.Message:
    """``send ID DLC B0 .. B(DLC-1)`` (hex) -> a Message; ProtocolError names what is wrong."""
    if len(words) < 3:
        raise ProtocolError("send needs an id and a length")
    ident, dlc_text, data_words = words[1], words[2], words[3:]
    try:
        can_id, dlc, data = int(ident, 16), int(dlc_text, 16), bytes(int(b, 16) for b in data_words)
    except ValueError:
        raise ProtocolError("send: id, length and data bytes must be hexadecimal") from None
    extended = len(ident) > 3
    if can_id < 0 or can_id > (0x1FFFFFFF if extended else 0x7FF) or len(ident) > 8:
        raise ProtocolError(f"send: id {ident} out of range")
    if not 0 <= dlc <= 8 or len(data_words) != dlc or any(len(b) > 2 for b in data_words):
        raise ProtocolError(f"send: {len(data_words)} data bytes for length {dlc_text}")
    return can.Message(arbitration_id=can_id, is_extended_id=extended, data=data, dlc=dlc)


def _why(exc: BaseException) -> str:
    """An exception as one line: its type and its message."""
    return f"{type(exc).__name__}: {' '.join(str(exc).split())}"[:200]


def well_formed_send(text: bytes) -> bool:
    """Whether ``parse_send`` takes the command ``text``, checked without building a Message (a
    frame about to be dropped); False also for some it takes ("08" for 8), which it then decides."""
    match = _SEND.fullmatch(text)
    if match is None:
        return False
    ident, dlc, data = match.groups()
    return int(ident, 16) <= (0x1FFFFFFF if len(ident) > 3 else 0x7FF) and len(data.split()) == int(dlc)


class SocketcandServer:
    """Serves the python-can bus ``interface``/``channel`` as socketcand bus ``bus_name`` on host:port."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0, bus_name: str = "can0", interface: str = "virtual",
                 channel: str = "hil", limits: SocketcandLimits = SocketcandLimits()):
        self.host, self.bus_name, self.limits = host, bus_name, limits
        self.bus = can.Bus(interface=interface, channel=channel, receive_own_messages=False)
        self.clients: set[_Client] = set()
        self.connections = 0  #: open TCP connections, in handshake or raw mode
        self._stop = threading.Event()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._requested_port = port
        self.port = port
        self._thread = threading.Thread(target=self._run, name="socketcand-server", daemon=True)
        self._thread.start()
        if not self._ready.wait(10.0) or self._error is not None:
            self.bus.shutdown()
            raise OSError(f"socketcand server on {host}:{port} did not start: {self._error}")
        self._reader = threading.Thread(target=self._read_bus, name="socketcand-bus", daemon=True)
        self._reader.start()

    # --- the event loop ---------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as exc:  # reported to the constructor (bind failures)
            self._error = exc
            self._ready.set()

    async def _main(self) -> None:
        self.loop = asyncio.get_running_loop()
        self._closed = asyncio.Event()
        self._handlers: dict[asyncio.Task, asyncio.StreamWriter] = {}
        server = await asyncio.start_server(self._serve_client, self.host, self._requested_port,
                                            limit=_READ_BYTES)
        self.port = server.sockets[0].getsockname()[1]
        self._ready.set()
        async with server:
            await self._closed.wait()
        await close_handlers(self._handlers)

    def _read_bus(self) -> None:
        """Frames on the bus (from the device) go to every raw-mode client."""
        while not self._stop.is_set():
            try:
                msg = self.bus.recv(timeout=0.05)  # how late close() sees the stop: it waits for this thread
            except Exception:  # the bus was shut down under us
                return
            if msg is not None and not msg.is_error_frame:
                try:
                    self.loop.call_soon_threadsafe(self._fanout, frame_line(msg), None)
                except RuntimeError:  # the loop is closed: we are stopping
                    return

    def _room(self) -> tuple[int, int]:
        """(how many more frames the device takes now, how many waiting frames were dropped to
        make room for one at least). A python-can ``virtual`` channel's queues are unbounded, so a
        client sending faster than the device reads would grow them without end: beyond
        ``max_backlog_frames`` waiting in a receiver's queue, its oldest is dropped. On any other
        interface the kernel or the adapter bounds them (no limit here)."""
        queues = getattr(self.bus, "channel", None)
        if not isinstance(queues, list):
            return 1 << 30, 0
        room, dropped = self.limits.max_backlog_frames, 0
        for q in list(queues):
            if q is self.bus.queue:
                continue
            while q.qsize() >= self.limits.max_backlog_frames:
                try:
                    q.get_nowait()
                except queue.Empty:  # the device took it meanwhile
                    break
                dropped += 1
            room = min(room, self.limits.max_backlog_frames - q.qsize())
        return max(room, 1), dropped

    def _count_overrun(self, client: _Client, dropped: int, final: bool = False) -> None:
        """One WARNING line at the first overrun, then at most every ``overrun_log_interval_s``
        while it goes on, and one at the end of the session for what is left."""
        client.overrun += dropped
        now = time.monotonic()
        if client.overrun and (final or now - client.overrun_logged_at >= self.limits.overrun_log_interval_s):
            log.warning("socketcand client %s: %d frames dropped: sent faster than the device takes them "
                        "(more than %d waiting)", client.peer, client.overrun, self.limits.max_backlog_frames)
            client.overrun, client.overrun_logged_at = 0, now

    def _fanout(self, line: bytes, sender: _Client | None) -> None:
        for client in self.clients:
            if client is not sender:
                client.put(line)

    # --- one client -------------------------------------------------------------------------------
    async def _serve_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        sock = writer.get_extra_info("socket")
        if sock is not None:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        peer = writer.get_extra_info("peername")
        peer = f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) else "?"
        if self.connections >= self.limits.max_clients:
            log.warning("socketcand client %s refused: %d clients connected already", peer, self.connections)
            await self._refuse(writer, "too many clients")
            return
        self.connections += 1
        self._handlers[asyncio.current_task()] = writer
        client = _Client(writer, collections.deque(maxlen=self.limits.queue_frames), peer)
        sender = None
        buffer = bytearray()
        pending: collections.deque[bytes] = collections.deque()  # commands read, not yet done
        try:
            writer.write(b"< hi >")
            handshake = asyncio.get_running_loop().time() + self.limits.handshake_timeout_s
            for expected in (f"open {self.bus_name}", "rawmode"):
                if not pending and not await self._commands(reader, buffer, pending, handshake, peer):
                    return
                words = pending.popleft().decode("ascii").split()
                if words[0] == "open" and expected.startswith("open") and words[1:] != [self.bus_name]:
                    raise ProtocolError(f"no bus {' '.join(words[1:])[:32]} (this server has {self.bus_name})")
                if " ".join(words) != expected:
                    raise ProtocolError(f"expected {expected} here")
                writer.write(b"< ok >")
            self.clients.add(client)
            sender = asyncio.create_task(self._send_frames(client))
            while True:
                if not pending and not await self._commands(reader, buffer, pending, None, peer):
                    return
                # everything this client has sent so far, in order; the sends the device cannot
                # take are the oldest of them, dropped before any work is spent on them, so the
                # last request of a burst reaches the device at once and not behind the rest
                sends = sum(text.split(None, 1)[0] == b"send" for text in pending)
                room, dropped = self._room() if sends else (0, 0)
                skip = max(sends - room, 0)
                if skip + dropped:
                    self._count_overrun(client, skip + dropped)
                while pending:
                    text = pending.popleft()
                    words = text.split(None, 1)[:1]
                    if words == [b"send"]:
                        if skip:  # checked, not built: a malformed frame is refused, dropped or not
                            skip -= 1
                            if not well_formed_send(text):
                                parse_send(text.decode("ascii").split())
                            continue
                        msg = parse_send(text.decode("ascii").split())
                        self.bus.send(msg)
                        msg.timestamp = time.time()
                        self._fanout(frame_line(msg), client)  # a bus: the other clients see it too
                    elif text.split() == [b"echo"]:
                        client.put(b"< echo >")
                    else:
                        client.put(b"< error unknown command >")
        except ProtocolError as exc:
            log.warning("socketcand client %s refused: %s", peer, exc)
            await self._refuse(writer, str(exc))
        except (ConnectionError, OSError) as exc:  # a reset: the client died, or left with answers unread
            # (one that leaves during the handshake is a port check, as CanopenLink makes: not news)
            log.log(logging.WARNING if sender is not None else logging.DEBUG, "socketcand client %s lost: %s",
                    peer, _why(exc))
        except Exception as exc:  # a fault of this server: the client is closed and told nothing more
            log.warning("socketcand client %s closed: server error %s", peer, _why(exc))
        finally:
            self._count_overrun(client, 0, final=True)
            self.connections -= 1
            self._handlers.pop(asyncio.current_task(), None)
            self.clients.discard(client)
            client.queue.clear()
            if sender is not None:
                sender.cancel()
            writer.close()

    async def _commands(
        self, reader: asyncio.StreamReader, buffer: bytearray, out: collections.deque, deadline: float | None,
        peer: str = "?",
    ) -> bool:
        """Every complete ``< ... >`` command the client has sent (the text between the brackets)
        appended to ``out``, waiting for one at least; False when the client has gone (EOF) or is
        to be closed (a timeout, logged with its reason). Text outside the brackets is skipped."""
        loop = asyncio.get_running_loop()
        lim = self.limits
        started = None
        while True:
            done = 0
            for match in _COMMAND.finditer(buffer):  # a burst of commands is split at C speed
                text = match.group(1)
                if not text.isascii():
                    raise ProtocolError("commands are ASCII")
                if not text.strip():
                    raise ProtocolError("empty command")
                out.append(text)
                done = match.end()
            del buffer[:done]
            if done:
                return True
            start = buffer.find(b"<")
            if start < 0 and buffer.strip():
                raise ProtocolError("a command starts with '<'")
            if start > 0:
                del buffer[:start]  # whitespace before the '<'
            elif start < 0:
                buffer.clear()
            if len(buffer) > lim.max_command_bytes:
                raise ProtocolError(f"command longer than {lim.max_command_bytes} bytes")
            if buffer and started is None:
                started = loop.time()
            limit = (
                deadline
                if deadline is not None
                else (started + lim.partial_timeout_s if buffer else loop.time() + lim.idle_timeout_s)
            )
            try:
                chunk = await asyncio.wait_for(reader.read(_READ_BYTES), max(limit - loop.time(), 0.0))
            except asyncio.TimeoutError:
                if deadline is not None:
                    why = f"handshake not finished within {lim.handshake_timeout_s:g} s"
                elif buffer:
                    why = f"a command begun did not end within {lim.partial_timeout_s:g} s"
                else:
                    why = f"nothing sent for {lim.idle_timeout_s:g} s"
                log.warning("socketcand client %s closed: %s", peer, why)
                return False
            if not chunk:
                return False
            buffer += chunk

    async def _send_frames(self, client: _Client) -> None:
        """Writes the client's queued frames; a client that takes nothing for idle_timeout_s is closed."""
        try:
            while True:
                await client.ready.wait()
                client.ready.clear()
                while client.queue:
                    batch = [client.queue.popleft() for _ in range(min(len(client.queue), 256))]
                    client.writer.write(b"".join(batch))
                    await asyncio.wait_for(client.writer.drain(), self.limits.idle_timeout_s)
        except asyncio.TimeoutError:
            log.warning("socketcand client %s closed: read nothing for %g s (%d frames dropped so far)",
                        client.peer, self.limits.idle_timeout_s, client.dropped)
            client.writer.close()
        except (ConnectionError, OSError) as exc:
            if not client.writer.is_closing():  # (closed by its reader's side: logged there)
                log.warning("socketcand client %s lost: %s", client.peer, _why(exc))
            client.writer.close()

    async def _refuse(self, writer: asyncio.StreamWriter, reason: str) -> None:
        try:
            text = (
                reason.replace("<", "(").replace(">", ")").encode("ascii", "replace")
            )  # one frame, whatever it quotes
            writer.write(b"< error " + text + b" >")
            await asyncio.wait_for(writer.drain(), 1.0)
        except (asyncio.TimeoutError, ConnectionError, OSError):
            pass
        writer.close()

    # --- stopping ---------------------------------------------------------------------------------
    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self.loop.call_soon_threadsafe(self._closed.set)
            self._thread.join(timeout=5.0)
        self._reader.join(timeout=2.0)
        self.bus.shutdown()
