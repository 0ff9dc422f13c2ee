#!/usr/bin/env python3
"""Holds N idle TCP connections to a server for S seconds (for scripts/bench_service.sh).

Half of them send nothing; the other half send an incomplete request line, as a slow client
would. Prints how many the server closed before the end.
Usage: hold_connections.py http://127.0.0.1:PORT N SECONDS
"""
import socket
import sys
import time
from urllib.parse import urlparse

url, count, seconds = urlparse(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
conns = []
for i in range(count):
    s = socket.create_connection((url.hostname, url.port))
    if i % 2:
        s.sendall(b"GET /v1/jobs HTTP/1.1\r\nHost: x\r\n")
    s.setblocking(False)
    conns.append(s)
print(f"holding {len(conns)} connections", flush=True)
end = time.time() + seconds
closed = set()
while time.time() < end:
    for i, s in enumerate(conns):
        if i in closed:
            continue
        try:
            if s.recv(4096) == b"":
                closed.add(i)
        except BlockingIOError:
            pass
        except OSError:
            closed.add(i)
    time.sleep(0.5)
print(f"server closed {len(closed)} of {len(conns)} idle connections within {seconds:.0f} s", flush=True)
