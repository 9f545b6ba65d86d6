"""The floor of one hop: Python processes passing a message around a ring over Zenoh, nothing else.

Each of ``--processes`` nodes is a separate process in peer mode behind a loopback router (as the
services of the ``lockstep`` profile) and receives as a service does: the Zenoh callback puts the
payload on a queue, the main thread takes it and publishes it to the next node. Node 0 times the round
trip. ``--listeners`` extra processes subscribe to every key (as the launcher and the sim listen to
maps and statuses beside the chain); ``--work-ms`` busy-waits in each node before it forwards (cold
caches, as a service that computes between messages).

    python benchmarks/bench_zenoh_hop.py [--processes 5] [--listeners 0] [--work-ms 0] [--rounds 300]

Per hop = round trip / processes (work included when ``--work-ms`` is set).
"""

from __future__ import annotations

import argparse
import json
import queue
import subprocess
import sys
import time

import numpy as np
import zenoh

from cso_runtime.transport import TransportConfig, free_tcp_port, loopback_endpoint, open_session

KEY = "bench/hop"


def peer(router_port: int) -> TransportConfig:
    return TransportConfig(mode="peer", connect=[loopback_endpoint(router_port)], listen=[loopback_endpoint(free_tcp_port())])


def receiver(inbox: queue.SimpleQueue, direct: bool):
    """The subscriber's callback: on a Python thread of its own (Zenoh's default) or, ``direct``, on Zenoh's network thread."""
    put = lambda sample: inbox.put(sample.payload.to_bytes())  # noqa: E731
    return zenoh.handlers.Callback(put, indirect=not direct)


def node(index: int, processes: int, router_port: int, rounds: int, size: int, work_s: float, settle_s: float, direct: bool = False) -> None:
    """One node of the ring; node 0 prints the round-trip times (s) as JSON."""
    inbox: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    with open_session(peer(router_port)) as session:
        pub = session.declare_publisher(f"{KEY}/{(index + 1) % processes}")
        sub = session.declare_subscriber(f"{KEY}/{index}", receiver(inbox, direct))
        time.sleep(settle_s)  # every node's subscriber is declared and known to its neighbour
        if index == 0:
            payload, times = b"x" * size, []
            for _ in range(rounds):
                t0 = time.perf_counter()
                pub.put(payload)
                inbox.get(timeout=10.0)
                times.append(time.perf_counter() - t0)
                time.sleep(0.002)  # a gap, as between lockstep steps
            print(json.dumps(times), flush=True)
        else:
            for _ in range(rounds):
                payload = inbox.get(timeout=30.0)
                t0 = time.perf_counter()
                while time.perf_counter() - t0 < work_s:
                    pass
                pub.put(payload)
        sub.undeclare()


def listener(router_port: int, seconds: float, direct: bool = False) -> None:
    """Subscribes to every key of the ring and handles each message on its main thread."""
    inbox: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    with open_session(peer(router_port)) as session:
        sub = session.declare_subscriber(f"{KEY}/**", receiver(inbox, direct))
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                inbox.get(timeout=0.1)
            except queue.Empty:
                pass
        sub.undeclare()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--processes", type=int, default=5)
    p.add_argument("--listeners", type=int, default=0)
    p.add_argument("--work-ms", type=float, default=0.0)
    p.add_argument("--rounds", type=int, default=300)
    p.add_argument("--size", type=int, default=1500, help="Payload bytes (a map message of the middle scene is ~1.4 KB)")
    p.add_argument("--direct", action="store_true", help="Run the callbacks on Zenoh's network thread (indirect=False)")
    p.add_argument("--role", default="main", help=argparse.SUPPRESS)
    p.add_argument("--index", type=int, default=0, help=argparse.SUPPRESS)
    p.add_argument("--router-port", type=int, default=0, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    settle_s = 2.0
    if args.role == "node":
        node(args.index, args.processes, args.router_port, args.rounds, args.size, args.work_ms / 1e3, settle_s, args.direct)
        return 0
    if args.role == "listener":
        listener(args.router_port, settle_s + args.rounds * 0.05 + 10.0, args.direct)
        return 0
    port = free_tcp_port()
    common = [sys.executable, __file__, "--processes", str(args.processes), "--rounds", str(args.rounds), "--size", str(args.size), "--work-ms", str(args.work_ms), "--router-port", str(port), *(["--direct"] if args.direct else [])]
    with open_session(TransportConfig(mode="router", listen=[loopback_endpoint(port)])):
        extra = [subprocess.Popen([*common, "--role", "listener"]) for _ in range(args.listeners)]
        nodes = [subprocess.Popen([*common, "--role", "node", "--index", str(i)], stdout=subprocess.PIPE if i == 0 else None, text=True) for i in range(args.processes)]
        try:
            out, _ = nodes[0].communicate(timeout=settle_s + args.rounds * 0.1 + 60)
        finally:
            for proc in nodes + extra:
                proc.kill()
                proc.wait()
    times = np.array(json.loads(out.strip().splitlines()[-1]))[20:] * 1e3  # the first rounds warm up
    report = {
        "processes": args.processes,
        "listeners": args.listeners,
        "work_ms_per_node": args.work_ms,
        "payload_bytes": args.size,
        "direct_callbacks": args.direct,
        "round_trip_ms": {"p50": round(float(np.median(times)), 3), "p90": round(float(np.percentile(times, 90)), 3)},
        "per_hop_ms_p50": round(float(np.median(times)) / args.processes, 3),
    }
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
