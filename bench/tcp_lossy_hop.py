"""How long a small request and its reply take over TCP through one lossy hop.

    .venv/bin/python bench/tcp_lossy_hop.py [--loss 0.35] [--requests 300] [--linear]

Needs CAP_NET_ADMIN (root). Two network namespaces joined by a veth; nftables drops
`--loss` of the TCP packets each way (data and ACKs alike, as the emulated radio
drops a pair's packets). A client sends 60 bytes every 200 ms and waits for the echo:
an idle, thin stream, as a command to a drone is. `--linear` sets Linux's thin-stream
linear timeouts (`net.ipv4.tcp_thin_linear_timeouts`) in both namespaces. Prints the
round trips' p50, p99 and max and how many took over 1, 2 and 3 s; exits 1 when any
took over 3 s (the issue's bar for a command). Measured figures: ADR 0003, "Not solved".
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys

SERVER = """
import socket
s = socket.socket(); s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
s.bind(("10.9.0.2", 9000)); s.listen(1)
c, _ = s.accept(); c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
while (data := c.recv(64)):
    c.sendall(data)
"""
CLIENT = """
import socket, sys, time
c = socket.create_connection(("10.9.0.2", 9000), timeout=120); c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
for _ in range(int(sys.argv[1])):
    t = time.monotonic(); c.sendall(b"x" * 60); got = 0
    while got < 60:
        got += len(c.recv(64))
    took = time.monotonic() - t
    print(f"{took:.4f}", flush=True)
    time.sleep(max(0.0, 0.2 - took))
"""


def sh(*args: str, stdin: str | None = None) -> None:
    subprocess.run(args, input=stdin, check=True, capture_output=True, text=True)


def measure(loss: float, requests: int, linear: bool) -> list[float]:
    tag = f"{os.getpid()}"
    a, b = f"tcphop-{tag}-a", f"tcphop-{tag}-b"
    sh("ip", "netns", "add", a)
    try:
        sh("ip", "netns", "add", b)
        sh("ip", "link", "add", "hop0", "netns", a, "type", "veth", "peer", "name", "hop1", "netns", b)
        for ns, dev, addr in ((a, "hop0", "10.9.0.1/24"), (b, "hop1", "10.9.0.2/24")):
            sh("ip", "-n", ns, "addr", "add", addr, "dev", dev)
            sh("ip", "-n", ns, "link", "set", dev, "up")
            sh("ip", "netns", "exec", ns, "sh", "-c",
               f"echo {int(linear)} > /proc/sys/net/ipv4/tcp_thin_linear_timeouts")
        k = round(loss * 1000)
        sh("ip", "netns", "exec", b, "nft", "-f", "-", stdin=(
            "table inet lossy {\n"
            f"  chain i {{ type filter hook input priority 0; policy accept; tcp dport 9000 numgen random mod 1000 < {k} drop; }}\n"
            f"  chain o {{ type filter hook output priority 0; policy accept; tcp sport 9000 numgen random mod 1000 < {k} drop; }}\n"
            "}\n"))
        server = subprocess.Popen(["ip", "netns", "exec", b, sys.executable, "-c", SERVER])
        try:
            client = subprocess.run(["ip", "netns", "exec", a, sys.executable, "-c", CLIENT, str(requests)],
                                    capture_output=True, text=True, timeout=requests * 60)
        finally:
            server.kill()
            server.wait()
        if client.returncode != 0:
            raise SystemExit(f"the client failed: {client.stderr[-2000:]}")
        return [float(line) for line in client.stdout.split()]
    finally:
        for ns in (a, b):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loss", type=float, default=0.35, help="share of packets lost each way")
    parser.add_argument("--requests", type=int, default=300)
    parser.add_argument("--linear", action="store_true", help="thin-stream linear timeouts at both ends")
    args = parser.parse_args()
    took = sorted(measure(args.loss, args.requests, args.linear))
    over = {s: sum(t > s for t in took) for s in (1, 2, 3)}
    print(f"loss {args.loss:.0%} each way, linear timeouts {'on' if args.linear else 'off'}: {len(took)} round trips, "
          f"p50 {took[len(took) // 2]:.2f} s, p99 {took[int(len(took) * 0.99)]:.2f} s, max {took[-1]:.2f} s; "
          f"over 1 s {over[1]}, over 2 s {over[2]}, over 3 s {over[3]}")
    return 1 if over[3] else 0


if __name__ == "__main__":
    sys.exit(main())
