#!/usr/bin/env python3
"""A command node (a profile's ``services.<name>.command``) as a node in another language would be one: nothing of
cso-runtime, only the Zenoh binding and msgpack, and the run's environment (docs/own-service.md, A node in any
language). It opens its session from ``$ZENOH_CONFIG``, subscribes to the robot's map (``$CSO_KEY_PREFIX/map``) and
appends ``<schema> <step>`` per map to the file its first argument names, and publishes the step on a topic of its
own, ``$CSO_KEY_PREFIX/ext/<$CSO_NODE_NAME>/steps``; it declares ``$CSO_ALIVE_KEY`` once
subscribed (the profile's ``alive_token: true``: step 0 waits for it) and writes its pid to
``$CSO_RUN_DIR/<$CSO_NODE_NAME>.pid``. ``--stubborn``: it ignores SIGTERM and starts a ``sleep`` of its own, whose pid
it writes to ``<name>.child.pid``: what must not outlive a killed launcher either. ``--daemon``: it starts a ``sleep``
as a daemon starts (a double fork and ``setsid``: out of the node's process group and session, its parent gone), whose
pid it writes to ``<name>.daemon.pid``: what ``down`` must stop all the same."""

import os
import signal
import subprocess
import sys
import threading

import msgpack
import zenoh


def listen(out_path: str, stop: threading.Event) -> None:
    """Append ``<schema> <step>`` to ``out_path`` for each map of the robot, until ``stop`` is set."""
    with zenoh.open(zenoh.Config.from_env()) as session, open(out_path, "a") as out:  # $ZENOH_CONFIG: the run's router
        steps = session.declare_publisher(f"{os.environ['CSO_KEY_PREFIX']}/ext/{os.environ['CSO_NODE_NAME']}/steps")

        def on_map(sample: zenoh.Sample) -> None:
            msg = msgpack.unpackb(sample.payload.to_bytes(), raw=False)  # {"schema": "map", "v": 3, "body": {...}}
            out.write(f"{msg['schema']} {msg['body']['step']}\n")
            out.flush()
            steps.put(str(msg["body"]["step"]).encode())  # a topic of its own: any payload

        subscriber = session.declare_subscriber(f"{os.environ['CSO_KEY_PREFIX']}/map", on_map)
        token = session.liveliness().declare_token(os.environ["CSO_ALIVE_KEY"])  # `alive_token: true`: step 0 waits for it
        print(f"{os.environ['CSO_NODE_NAME']}: listening on {os.environ['CSO_KEY_PREFIX']}/map", flush=True)
        stop.wait()
        token.undeclare()
        subscriber.undeclare()
        steps.undeclare()


def start_daemon(pid_path: str) -> None:
    """``sleep 600`` as a daemon: a double fork and ``setsid``, its pid in ``pid_path``; before any thread is started."""
    first = os.fork()
    if first == 0:
        os.setsid()
        if os.fork() == 0:
            with open(pid_path, "w") as fh:
                fh.write(str(os.getpid()))
            os.execvp("sleep", ["sleep", "600"])
        os._exit(0)
    os.waitpid(first, 0)


def main() -> int:
    out_path, stubborn = sys.argv[1], "--stubborn" in sys.argv[2:]
    stop = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    signal.signal(signal.SIGTERM, signal.SIG_IGN if stubborn else lambda *_: stop.set())
    run_dir, name = os.environ["CSO_RUN_DIR"], os.environ["CSO_NODE_NAME"]
    if stubborn:
        child = subprocess.Popen(["sleep", "600"])
        with open(os.path.join(run_dir, f"{name}.child.pid"), "w") as fh:
            fh.write(str(child.pid))
    if "--daemon" in sys.argv[2:]:
        start_daemon(os.path.join(run_dir, f"{name}.daemon.pid"))
    with open(os.path.join(run_dir, f"{name}.pid"), "w") as fh:
        fh.write(str(os.getpid()))
    print(f"{name}: joins {os.environ['CSO_ZENOH_ENDPOINTS']} as robot {os.environ['CSO_ROBOT']}", flush=True)
    listen(out_path, stop)
    print(f"{name}: stopped", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
