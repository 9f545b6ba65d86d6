"""Where a lockstep step's time goes: every traced event of every service, as the median time after the
sim's scan of its step, for keep-goal steps and decision steps apart (BENCHMARKS.md's step timelines).

Reads the services' message traces of one episode (``CSO_TRACE_DIR``, ``services.common.MessageTrace``).
An event is a publication (``put``: its ``encode`` is done) or a handled input in three phases: Zenoh's
callback (``callback``), the handler's start after the queue and ``decode`` (``start``) and its end
(``end``). A decision step is one whose goal the policy published. Also prints each kind of step's
median and mean duration (scan to next scan).

    CSO_TRACE_DIR=DIR cso-runtime up --profile lockstep --scene generated:middle:1:0 --method cso --no-live
    python benchmarks/step_timeline.py DIR [--json out.json]
"""

from __future__ import annotations

import argparse
import itertools
import json
import statistics
from collections import defaultdict
from pathlib import Path

SERVICES = ("sim", "mapper", "frontier", "planner", "policy")
PHASES = ("callback", "start", "end")
"""The three times of a handled input (``MessageTrace.handled``), after its kind, topic and step."""


def load_traces(trace_dir: Path) -> dict[str, list[list]]:
    """Each service's trace events (services without a trace file are left out)."""
    return {s: json.loads(p.read_text()) for s in SERVICES if (p := trace_dir / f"{s}.trace.json").is_file()}


def timeline(traces: dict[str, list[list]]) -> dict[str, dict]:
    """For ``keep`` and ``decision`` steps: the step count, the median and mean step (ms), and each event's
    median ms after the sim's scan of its step (``"planner handle frontiers start"``, ``"sim put scan"``)."""
    scan_s = {e[2]: e[3] for e in traces.get("sim", []) if e[0] == "put" and e[1] == "scan"}
    if not scan_s:
        raise SystemExit("no sim trace with scans: was the episode run with CSO_TRACE_DIR set?")
    decided = {e[2] for e in traces.get("policy", []) if e[0] == "put" and e[1] == "goal"}
    kind_of = {step: "decision" if step in decided else "keep" for step in scan_s}
    after: dict[str, dict[str, list[float]]] = {"keep": defaultdict(list), "decision": defaultdict(list)}
    for service, rows in traces.items():
        for kind, topic, step, *times in rows:
            if step not in scan_s:
                continue
            phases = (("", times[0]),) if kind == "put" else tuple(zip(PHASES, times))
            for phase, t_s in phases:
                name = f"{service} {kind} {topic}" + (f" {phase}" if phase else "")
                after[kind_of[step]][name].append((t_s - scan_s[step]) * 1e3)
    steps = sorted(scan_s)
    durations: dict[str, list[float]] = {"keep": [], "decision": []}
    for step, nxt in itertools.pairwise(steps):
        durations[kind_of[step]].append((scan_s[nxt] - scan_s[step]) * 1e3)
    out = {}
    for k in ("keep", "decision"):
        d = durations[k]
        events = sorted(((statistics.median(v), name) for name, v in after[k].items()), key=lambda x: x[0])
        out[k] = {
            "steps": len(d),
            "step_ms_median": statistics.median(d) if d else None,
            "step_ms_mean": statistics.fmean(d) if d else None,
            "events_ms_median": {name: round(ms, 4) for ms, name in events},
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("trace_dir", type=Path)
    parser.add_argument("--json", type=Path, help="Also write the timelines here")
    args = parser.parse_args()
    result = timeline(load_traces(args.trace_dir))
    for k, t in result.items():
        if not t["steps"]:
            continue
        print(f"{k} steps: {t['steps']}, step median {t['step_ms_median']:.2f} ms, mean {t['step_ms_mean']:.2f} ms")
        for name, ms in t["events_ms_median"].items():
            print(f"  {ms:8.3f}  {name}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
