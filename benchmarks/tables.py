"""Print Table 1-style markdown rows (per method and per scale) from eval ``summary.json`` files.

    python benchmarks/tables.py results/easy/summary.json [more summary.json ...]

Used to write BENCHMARKS.md from the committed results without copying numbers by hand.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

COLUMNS = ("explored_area_m2", "coverage_pct", "steps", "efficiency_m2_per_step", "path_length_m", "decision_ms_p50", "decision_ms_p99")
HEADER = "| scale | method | episodes | explored m2 | coverage % | steps | m2/step | path m | decision ms p50 / p99 |"


def fmt(v, nd: int) -> str:
    return "-" if v is None else f"{v:.{nd}f}"


def rows(summary: dict) -> list[str]:
    out = []
    for method, entry in summary["methods"].items():
        for scale, e in entry["by_scale"].items():
            out.append(
                f"| {scale} | {method} | {e['episodes']} | {fmt(e['explored_area_m2'], 1)} | {fmt(e['coverage_pct'], 2)} | "
                f"{fmt(e['steps'], 1)} | {fmt(e['efficiency_m2_per_step'], 4)} | {fmt(e['path_length_m'], 1)} | "
                f"{fmt(e['decision_ms_p50'], 1)} / {fmt(e['decision_ms_p99'], 1)} |"
            )
    return out


def main(paths: list[str]) -> None:
    if not paths:
        raise SystemExit(__doc__)
    missing = [p for p in paths if not Path(p).is_file()]
    if missing:
        raise SystemExit(f"error: no such file: {', '.join(missing)}")
    print(HEADER)
    print("| --- " * 9 + "|")
    for p in paths:
        for r in rows(json.loads(Path(p).read_text())):
            print(r)


if __name__ == "__main__":
    main(sys.argv[1:])
