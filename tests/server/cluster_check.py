#!/usr/bin/python3
"""Checks a running local cluster (scripts/cluster.sh starts one and runs this while the load tester runs).

Through the proxy and around it:
  - ListSessions through the proxy lists every server's sessions (the union of each server's own list);
  - Watch reaches a session wherever it lives: on every server, a session of every *other* server is
    watched directly (so it must be relayed) and through the proxy; frame indexes must increase;
  - the browser's /ws/watch works through the proxy and directly on a server that does not hold the session;
  - Watch of an unknown session is NOT_FOUND through the proxy.
Prints one line per check and exits 1 if any failed.

  cluster_check.py --proxy 127.0.0.1:P --servers G1/H1,G2/H2,... [--min-sessions N]
"""
import argparse
import base64
import json
import os
import socket
import struct
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "client", "python"))

import grpc  # noqa: E402

from dance.v1 import dance_pb2, dance_pb2_grpc  # noqa: E402

PEER = (("x-dance-peer", "1"),)  # a server answers such calls from its own sessions only
failures = []


def check(ok, what):
    print(("ok    " if ok else "FAIL  ") + what, flush=True)
    if not ok:
        failures.append(what)


def stub(addr):
    return dance_pb2_grpc.DanceServiceStub(grpc.insecure_channel(addr))


def own_sessions(grpc_addr):
    resp = stub(grpc_addr).ListSessions(dance_pb2.ListSessionsRequest(), metadata=PEER, timeout=5)
    return [s.session_id for s in resp.sessions]


def watch_frames(addr, session_id, n=5, timeout=20):
    """The indexes of the first n frames a Watch through addr gets."""
    indexes = []
    call = stub(addr).Watch(dance_pb2.WatchRequest(session_id=session_id, omit_rotations=True), timeout=timeout)
    try:
        for u in call:
            if u.HasField("frame"):
                indexes.append(u.frame.index)
                if len(indexes) >= n:
                    break
    finally:
        call.cancel()
    return indexes


def ws_watch_frames(host_port, session_id, n=3, timeout=20):
    """The indexes of the first n frames of /ws/watch through host_port (a minimal RFC 6455 client)."""
    host, port = host_port.rsplit(":", 1)
    s = socket.create_connection((host, int(port)), timeout=timeout)
    key = base64.b64encode(os.urandom(16)).decode()
    s.sendall((f"GET /ws/watch?session={session_id} HTTP/1.1\r\nHost: {host_port}\r\nUpgrade: websocket\r\n"
               f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n").encode())
    buf = b""
    while b"\r\n\r\n" not in buf:
        chunk = s.recv(4096)
        if not chunk:
            raise IOError("connection closed before the handshake ended: %r" % buf[:200])
        buf += chunk
    head, buf = buf.split(b"\r\n\r\n", 1)
    if not head.startswith(b"HTTP/1.1 101"):
        raise IOError("no upgrade: %r" % head[:200])

    def need(k):
        nonlocal buf
        while len(buf) < k:
            chunk = s.recv(65536)
            if not chunk:
                raise IOError("connection closed mid-frame")
            buf += chunk

    indexes = []
    while len(indexes) < n:
        need(2)
        b0, b1 = buf[0], buf[1]
        length, off = b1 & 0x7F, 2
        if length == 126:
            need(4)
            length, off = struct.unpack(">H", buf[2:4])[0], 4
        elif length == 127:
            need(10)
            length, off = struct.unpack(">Q", buf[2:10])[0], 10
        need(off + length)
        payload, buf = buf[off:off + length], buf[off + length:]
        if b0 & 0x0F == 1:  # text
            msg = json.loads(payload)
            if msg.get("type") == "frame":
                indexes.append(msg["index"])
        elif b0 & 0x0F == 8:
            break
    s.close()
    return indexes


def increasing(xs):
    return len(xs) > 0 and all(b > a for a, b in zip(xs, xs[1:]))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--proxy", required=True)
    ap.add_argument("--servers", required=True, help="GRPC_PORT/HTTP_PORT,... on 127.0.0.1")
    ap.add_argument("--min-sessions", type=int, default=1)
    a = ap.parse_args()
    servers = [tuple("127.0.0.1:" + p for p in s.split("/")) for s in a.servers.split(",")]

    own = {g: own_sessions(g) for g, _ in servers}
    union = set(x for ids in own.values() for x in ids)
    print("sessions per server: " + ", ".join(str(len(own[g])) for g, _ in servers), flush=True)
    check(len(union) >= a.min_sessions, f"{len(union)} live sessions (>= {a.min_sessions})")
    listed = stub(a.proxy).ListSessions(dance_pb2.ListSessionsRequest(), timeout=10)
    listed_ids = set(s.session_id for s in listed.sessions)
    # Sessions start and end while we look: the proxy's list must hold every session that was live both
    # before and after it was taken.
    after = set(x for g, _ in servers for x in own_sessions(g))
    stable = union & after
    check(stable <= listed_ids and len(listed.sessions) == len(listed_ids),
          f"ListSessions through the proxy: {len(listed_ids)} sessions, every server's ({len(stable)} stable) "
          f"listed once")

    for i, (g, h) in enumerate(servers):
        for j, (og, _) in enumerate(servers):
            if i == j or not own[og]:
                continue
            sid = sorted(set(own[og]) & after)[0] if set(own[og]) & after else own[og][0]
            try:
                idx = watch_frames(g, sid)
                check(increasing(idx) and len(idx) == 5,
                      f"Watch on server {i + 1} of a session on server {j + 1} (relayed): frames {idx}")
            except grpc.RpcError as e:
                check(False, f"Watch on server {i + 1} of a session on server {j + 1}: {e.code()} {e.details()}")
            try:
                idx = ws_watch_frames(h, sid)
                check(increasing(idx), f"/ws/watch on server {i + 1} of a session on server {j + 1}: frames {idx}")
            except (IOError, OSError, ValueError) as e:
                check(False, f"/ws/watch on server {i + 1} of a session on server {j + 1}: {e}")

    for j, (og, _) in enumerate(servers):
        live = sorted(set(own[og]) & after)
        if not live:
            continue
        try:
            idx = watch_frames(a.proxy, live[0])
            check(increasing(idx), f"Watch through the proxy of a session on server {j + 1}: frames {idx}")
        except grpc.RpcError as e:
            check(False, f"Watch through the proxy of a session on server {j + 1}: {e.code()} {e.details()}")
        try:
            idx = ws_watch_frames(a.proxy, live[0])
            check(increasing(idx), f"/ws/watch through the proxy of a session on server {j + 1}: frames {idx}")
        except (IOError, OSError, ValueError) as e:
            check(False, f"/ws/watch through the proxy of a session on server {j + 1}: {e}")

    t0 = time.time()
    try:
        watch_frames(a.proxy, "s-00000000deadbeef", n=1)
        check(False, "Watch of an unknown session through the proxy: frames?")
    except grpc.RpcError as e:
        check(e.code() == grpc.StatusCode.NOT_FOUND,
              f"Watch of an unknown session through the proxy: {e.code()} after {time.time() - t0:.2f} s")

    print(f"cluster_check: {len(failures)} failed", flush=True)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
