"""A real websocket server on 127.0.0.1 that sends fixed bytes: hostile openpi metadata and replies."""

from __future__ import annotations

import contextlib
import threading


@contextlib.contextmanager
def serve_bytes(metadata: bytes, reply: bytes | None = None):
    """Send ``metadata`` on connect, then ``reply`` (if given) to every request; yields the ws:// URI."""
    from websockets.sync.server import serve

    def handler(ws):
        ws.send(metadata)
        with contextlib.suppress(Exception):
            for _ in ws:
                if reply is not None:
                    ws.send(reply)

    with serve(handler, "127.0.0.1", 0, max_size=None, compression=None) as server:
        thread = threading.Thread(target=server.serve_forever, daemon=True)
        thread.start()
        try:
            yield f"ws://127.0.0.1:{server.socket.getsockname()[1]}"
        finally:
            server.shutdown()
            thread.join(5)
