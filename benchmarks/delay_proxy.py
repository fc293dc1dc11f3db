"""A TCP forwarder that delays every byte a fixed time in each direction: a remote machine's
network in user space, for where ``tc netem`` (``benchmarks.netns``) is not available.

Each chunk read from one side is written to the other ``delay`` seconds after it was read, in
order. A new connection also pays the TCP handshake a real link would cost (one round trip)
before its first byte arrives: its first chunk goes out no sooner than ``2 * delay`` after accept
plus ``delay``. Unlike netem it delays reads, not packets, so it may merge what netem would keep
apart; for request/response traffic (HTTP orders, MQTT publish/PUBACK) the two agree to well
within the delay.

Runs an asyncio loop in a thread of its own; use as a context manager.
"""

from __future__ import annotations

import asyncio
import threading
import time
from types import TracebackType


class DelayProxy:
    """Listens on ``listen_host``:``port`` (free, chosen by the OS) and forwards to target."""

    def __init__(self, target_host: str, target_port: int, delay_s: float, listen_host: str = "127.0.0.1"):
        self.target = (target_host, target_port)
        self.delay = delay_s
        self.listen_host = listen_host
        self.port = 0
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="delay-proxy", daemon=True)
        self._server: asyncio.AbstractServer | None = None

    def __enter__(self) -> DelayProxy:
        self._thread.start()
        self._server = asyncio.run_coroutine_threadsafe(
            asyncio.start_server(self._handle, self.listen_host, 0), self._loop).result(10)
        self.port = self._server.sockets[0].getsockname()[1]
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None) -> None:
        async def close() -> None:
            assert self._server is not None
            self._server.close()
            tasks = asyncio.all_tasks() - {asyncio.current_task()}
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)

        asyncio.run_coroutine_threadsafe(close(), self._loop).result(10)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)
        self._loop.close()

    async def _handle(self, client_r: asyncio.StreamReader, client_w: asyncio.StreamWriter) -> None:
        not_before = time.monotonic() + 2 * self.delay  # the handshake's round trip
        try:
            up_r, up_w = await asyncio.open_connection(*self.target)
            await asyncio.gather(self._pipe(client_r, up_w, not_before), self._pipe(up_r, client_w, not_before),
                                 return_exceptions=True)
        except OSError:
            client_w.close()
        except asyncio.CancelledError:  # the proxy closes: end quietly (streams would log a cancelled handler)
            client_w.close()

    async def _pipe(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, not_before: float) -> None:
        queue: asyncio.Queue[tuple[float, bytes]] = asyncio.Queue()

        async def send() -> None:
            while True:
                due, chunk = await queue.get()
                await asyncio.sleep(max(0.0, due - time.monotonic()))
                if not chunk:
                    break
                writer.write(chunk)
                await writer.drain()

        sender = asyncio.ensure_future(send())
        try:
            while True:
                chunk = await reader.read(65536)
                queue.put_nowait((max(time.monotonic(), not_before) + self.delay, chunk))
                if not chunk:
                    break
            await sender
        finally:
            sender.cancel()
            writer.close()
