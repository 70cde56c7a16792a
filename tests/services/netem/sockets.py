"""Real-socket helpers for the netem proxy tests: a UDP sink/echo, a TCP echo, clients, polling."""

from __future__ import annotations

import socket
import struct
import threading
import time

from tests.conftest import wait_until


class UdpServer:
    """A UDP sink that records (arrival time, payload) and optionally echoes."""

    def __init__(self, echo: bool = False) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.echo, self.got, self.peers = echo, [], set()
        self._stop = False
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    @property
    def address(self):
        return self.sock.getsockname()

    def _run(self) -> None:
        while not self._stop:
            try:
                data, peer = self.sock.recvfrom(65535)
            except TimeoutError:
                continue
            except OSError:
                return
            self.got.append((time.monotonic(), data))
            self.peers.add(peer)
            if self.echo:
                self.sock.sendto(data, peer)

    def wait_count(self, n: int, timeout: float = 5.0) -> None:
        eventually(lambda: len(self.got) >= n, timeout)

    def close(self) -> None:
        self._stop = True
        self.thread.join()
        self.sock.close()


class TcpEcho:
    """A TCP echo server, one thread per connection."""

    def __init__(self) -> None:
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen()
        self.sock.settimeout(0.1)
        self._stop = False
        self.accepted = 0
        self.threads = [threading.Thread(target=self._run, daemon=True)]
        self.threads[0].start()

    @property
    def address(self):
        return self.sock.getsockname()

    def _run(self) -> None:
        while not self._stop:
            try:
                conn, _ = self.sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            self.accepted += 1
            t = threading.Thread(target=self._echo, args=(conn,), daemon=True)
            self.threads.append(t)
            t.start()

    @staticmethod
    def _echo(conn: socket.socket) -> None:
        with conn:
            try:
                while data := conn.recv(1 << 16):
                    conn.sendall(data)
            except OSError:
                pass

    def close(self) -> None:
        self._stop = True
        self.threads[0].join()
        self.sock.close()


def netem_threads() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name.startswith("netem-")]


def udp_client() -> socket.socket:
    c = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    c.settimeout(2.0)
    return c


def eventually(pred, timeout: float = 5.0) -> bool:
    """Poll ``pred`` until true (or timeout): waits for the proxy threads to catch up."""
    return wait_until(pred, timeout, poll=0.01)


def send_paced(sock: socket.socket, addr, payloads, every: int = 50, pause: float = 0.002) -> None:
    """Send datagrams with a short pause every few, so no socket buffer overflows on the way."""
    for i, p in enumerate(payloads):
        sock.sendto(p, addr)
        if i % every == every - 1:
            time.sleep(pause)


def rtt_ms(sock: socket.socket, addr, n: int = 15) -> list[float]:
    out = []
    for i in range(n):
        t = time.monotonic()
        sock.sendto(struct.pack("!I", i), addr)
        while struct.unpack("!I", sock.recvfrom(100)[0][:4])[0] != i:
            pass
        out.append((time.monotonic() - t) * 1000.0)
        time.sleep(0.005)
    return out
