"""A counting proxy in front of an S3 server on loopback (tests/s3server.py): every request
counted by kind (method and cache area), with an optional delay per request (a real store's
latency).  Used by benchmarks/bench_s3.py and the request-budget test."""
from __future__ import annotations

import collections
import http.client
import http.server
import os
import sys
import threading
import time
import urllib.parse
from typing import Callable

from s3server import free_port


class Counter:
    """Requests by kind (see :func:`kind_of`), counted by a proxy (:func:`make_proxy`)."""

    def __init__(self):
        self.lock = threading.Lock()
        self.kinds: collections.Counter = collections.Counter()

    def add(self, kind: str) -> None:
        with self.lock:
            self.kinds[kind] += 1

    def take(self) -> collections.Counter:
        with self.lock:
            out, self.kinds = self.kinds, collections.Counter()
        return out


#: the cache's top-level parts, as the request breakdown names them (what each request is for)
AREAS = {"locks": "lease", "active": "run-lease", "store.lock": "gc-lease", "keys": "record",
         "objects": "object", "journal": "journal", "runs": "run"}


def kind_of(method: str, path: str) -> str:
    """``METHOD area``: the HTTP verb and the part of the cache it touches (``/bench/cache/<part>/…``)."""
    if method == "GET" and ("list-type" in path or path.rstrip("/").count("/") <= 1):
        method = "LIST"
    elif method == "POST" and "delete" in path:
        method = "DELETE(batch)"
    where, _, query = path.partition("?")
    prefix = urllib.parse.parse_qs(query).get("prefix", [""])[0]
    parts = f"{where.strip('/')}/{prefix}".strip("/").split("/")
    area = AREAS.get(parts[2], parts[2]) if len(parts) > 2 else "bucket"
    return f"{method} {area}"


def make_proxy(upstream_port: int, counter: Counter, delay_s: float = 0.0,
               before: Callable[[str], bool | None] | None = None):
    """An HTTP proxy on loopback in front of the S3 server at ``upstream_port`` that counts every
    request and can add ``delay_s`` to each (a real store's latency); ``before(kind)`` is called
    with each request's kind before it is forwarded (a test may hold it there, or return True to
    answer it with a server error instead); ``.shutdown()`` ends it."""
    class Proxy(http.server.BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, *a):
            pass

        def _forward(self):
            kind = kind_of(self.command, self.path)
            counter.add(kind)
            n = int(self.headers.get("Content-Length") or 0)
            body = self.rfile.read(n) if n else None
            if before is not None and before(kind):  # answered here: a server error
                self.send_response(503, "Slow Down")
                self.send_header("Content-Length", "0")
                return self.end_headers()
            if os.environ.get("BENCH_S3_TRACE") == "1":  # print every request (method and path)
                print(self.command, self.path, file=sys.stderr)
            if delay_s:
                time.sleep(delay_s)
            conn = http.client.HTTPConnection("127.0.0.1", upstream_port, timeout=60)
            headers = {k: v for k, v in self.headers.items() if k.lower() not in ("connection",)}
            conn.request(self.command, self.path, body=body, headers=headers)
            r = conn.getresponse()
            data = r.read()
            self.send_response(r.status, r.reason)
            for k, v in r.getheaders():
                if k.lower() not in ("content-length", "connection", "transfer-encoding"):
                    self.send_header(k, v)
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            if self.command != "HEAD":
                self.wfile.write(data)
            conn.close()

        do_GET = do_PUT = do_POST = do_DELETE = do_HEAD = _forward

    class Server(http.server.ThreadingHTTPServer):
        request_queue_size = 128  # (the default 5 drops a batch's connections: a 1 s SYN retry)

    srv = Server(("127.0.0.1", free_port()), Proxy)
    srv.daemon_threads = True
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    return srv
