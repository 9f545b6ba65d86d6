"""Does the sim's step ahead hold up the command of a keep-goal step? Reads the services' message traces
of one lockstep episode and, for every step without a decision, compares the command's transit (planner's
put to the sim's callback) when the sim was still stepping ahead at the put and when it was not.

    CSO_TRACE_DIR=DIR cso-runtime up --profile lockstep --scene generated:middle:1:0 --method cso --runs-dir /tmp/runs
    python benchmarks/step_ahead_wait.py DIR
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path


def events(trace_dir: Path, service: str, kind: str, topic: str) -> dict[int, list]:
    """``MessageTrace`` events of one service, kind (``handle`` or ``put``) and topic, by step."""
    rows = json.loads((trace_dir / f"{service}.trace.json").read_text())
    return {row[2]: row for row in rows if row[0] == kind and row[1] == topic}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("trace_dir", type=Path)
    args = parser.parse_args()
    scan_put = events(args.trace_dir, "sim", "put", "scan")
    decided = events(args.trace_dir, "planner", "handle", "goal")
    cmd_put = events(args.trace_dir, "planner", "put", "cmd_vel")
    cmd_in = events(args.trace_dir, "sim", "handle", "cmd_vel")
    ahead = events(args.trace_dir, "sim", "handle", "cmd_vel_ahead")
    waited, free = [], []
    for step in scan_put:
        if step in decided or not (step in cmd_put and step in cmd_in and step in ahead):
            continue
        put_done_s, received_s, ahead_done_s = cmd_put[step][4], cmd_in[step][3], ahead[step][5]
        (waited if ahead_done_s > put_done_s else free).append((received_s - put_done_s) * 1e3)
    n = len(waited) + len(free)
    print(f"keep-goal steps: {n}; the step ahead still running when the command was put: {len(waited)}")
    for name, ms in (("then", waited), ("otherwise", free)):
        if ms:
            print(f"  command transit {name}: median {statistics.median(ms):.2f} ms over {len(ms)} steps")


if __name__ == "__main__":
    main()
