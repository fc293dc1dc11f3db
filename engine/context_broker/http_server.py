"""The context broker's HTTP server: waitress, with 204 answers that keep the connection open.

waitress reads every request whole (headers and body, asynchronously) before a worker thread
runs the app, so slow or stalled clients hold no worker: a well-behaved client is answered while
any number of others trickle their bodies in. Its one flaw for an NGSI server: waitress 3.0.2
closes an HTTP/1.1 connection after any response without ``Content-Length`` — including 204 and
304, which have no body by definition — and 204 is the answer to nearly every NGSI write, so each
write would cost a new TCP connection. :class:`KeepAliveTask` keeps such connections open
(unless the client asked to close, or waitress closes for another reason).
"""

from __future__ import annotations

import logging
from typing import Any

from waitress import create_server
from waitress.channel import HTTPChannel
from waitress.task import WSGITask

MAX_BODY_READ = 16 * 1024 * 1024  # waitress refuses larger bodies itself; the app's limit is 1 MB


class KeepAliveTask(WSGITask):
    def build_response_header(self) -> bytes:
        closing_before = self.close_on_finish
        client_closes = (self.version != "1.1"
                         or self.request.headers.get("CONNECTION", "").lower() == "close")
        header: bytes = super().build_response_header()
        if not self.has_body and not client_closes and not closing_before and self.close_on_finish:
            self.close_on_finish = False
            self.response_headers = [h for h in self.response_headers if h != ("Connection", "close")]
            header = header.replace(b"\r\nConnection: close", b"", 1)
        return header


class KeepAliveChannel(HTTPChannel):
    task_class = KeepAliveTask


def make_server(app: Any, host: str, port: int, threads: int) -> Any:
    """A waitress server for ``app`` (call ``run()``; ``close()`` stops it)."""
    logging.getLogger("waitress.queue").setLevel(logging.ERROR)  # "Task queue depth" chatter
    server = create_server(app, host=host, port=port, threads=threads, ident="plantkg-context-broker",
                           max_request_body_size=MAX_BODY_READ, clear_untrusted_proxy_headers=True)
    server.channel_class = KeepAliveChannel
    return server
