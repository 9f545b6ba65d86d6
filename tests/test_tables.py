"""benchmarks/tables.py: Table 1 rows pooled from episodes.csv files, as BENCHMARKS.md's Table 1 is written."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

from cso_runtime.evaluation import CSV_FIELDS
from tests.conftest import write_episodes_csv


def load_tables():
    spec = importlib.util.spec_from_file_location("tables", Path(__file__).parents[1] / "benchmarks" / "tables.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def episode(method: str, map_: str, scale: str, efficiency: float, steps: int = 100, p50: float = 10.0) -> dict:
    return {
        "method": method, "map": map_, "scale": scale, "seed": 0, "explored_area_m2": efficiency * steps,
        "coverage_pct": 99.5, "steps": steps, "efficiency_m2_per_step": efficiency, "path_length_m": 20.0,
        "decision_ms_p50": p50, "decision_ms_p99": 2 * p50, "terminated_by": "coverage",
        "traversable_area_m2": 150.0, "decisions": 30, "wall_s": 1.0,
    }


def write(path: Path, rows: list[dict]) -> Path:
    return write_episodes_csv(path, rows, CSV_FIELDS)


def cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def test_pools_episodes_per_scale_with_later_files_replacing_a_method_and_labels_apart(tmp_path, capsys):
    """Means per scale and method as eval's summary; the second file's cso replaces the first's on the same
    scenes of its label; plan "a" of two labels is two scenes; the paired cell compares scene by scene."""
    greedy = [episode("greedy-dist", m, "large", 1.0) for m in "abc"]
    first = write(tmp_path / "first.csv", greedy + [episode("cso", m, "large", 0.5) for m in "abc"])
    rerun = write(tmp_path / "rerun.csv", [episode("cso", m, "large", 1.2, p50=20.0) for m in "abc"])
    other = write(
        tmp_path / "other.csv",
        [episode("greedy-dist", "a", "large", 2.0), episode("cso", "a", "large", 2.0), episode("greedy-dist", "s", "small", 3.0)],
    )
    tables = load_tables()
    assert tables.main([f"easy={first}", f"easy={rerun}", f"medium={other}"]) == 0
    out = capsys.readouterr().out.splitlines()
    rows = {(c[0], c[1]): c for c in map(cells, out[2:])}
    assert set(rows) == {("small", "greedy-dist"), ("large", "greedy-dist"), ("large", "cso")}
    cso = rows[("large", "cso")]
    # four scenes: 1.2 three times (easy) and 2.0 once (medium); per scene +20 % three times and level once
    assert cso[2] == "4" and cso[6] == f"{(3 * 1.2 + 2.0) / 4:.4f}"
    assert cso[8] == f"{(3 * 20 + 10) / 4:.1f} / {(3 * 40 + 20) / 4:.1f}"
    mean, rest = cso[9].split(" % [")
    assert mean == "+15.0" and rest.endswith("], 3 won")
    assert rows[("large", "greedy-dist")][9] == "" and rows[("small", "greedy-dist")][2] == "1"


def test_an_episodes_csv_cut_short_mid_row_is_refused_not_pooled(tmp_path):
    """A file cut short in its last row (an interrupted copy) was pooled with that row's missing cells empty and a
    number cut short as a smaller one: a Table 1 row of wrong figures."""
    whole = write(tmp_path / "whole.csv", [episode("greedy-dist", m, "large", 1.0) for m in "abc"])
    text = whole.read_text()
    cut = tmp_path / "cut.csv"
    cut.write_text(text[: text.rindex("99.5") + 2])
    tables = load_tables()
    assert len(tables.pooled_rows([("", whole)])) == 3
    with pytest.raises(ValueError, match=f"line 4 has 6 cells, the header {len(CSV_FIELDS)} columns"):
        tables.pooled_rows([("", cut)])


def test_mixing_summaries_and_episode_files_is_refused(tmp_path, capsys):
    tables = load_tables()
    csv_file = write(tmp_path / "e.csv", [episode("greedy-dist", "a", "large", 1.0)])
    summary = tmp_path / "summary.json"
    summary.write_text("{}")
    with pytest.raises(SystemExit) as exc:
        tables.main([str(csv_file), str(summary)])
    assert exc.value.code == 2 and "not both" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        tables.main([str(tmp_path / "missing.csv")])
    assert exc.value.code == 2 and "no such file" in capsys.readouterr().err


def test_table2_has_a_row_per_method_and_a_column_per_scale(tmp_path, capsys):
    """The paper's Table 2 layout, as eval's report lays it out (``report.table2``)."""
    rows = [episode("greedy-dist", m, "large", 1.0) for m in "abc"] + [episode("cso", m, "large", 1.1) for m in "abc"]
    rows.append(episode("greedy-dist", "s", "small", 2.0))
    tables = load_tables()
    assert tables.main(["--table2", str(write(tmp_path / "e.csv", rows))]) == 0
    out = [cells(line) for line in capsys.readouterr().out.splitlines()]
    assert out[0] == ["method", "small", "large"]
    assert out[2] == ["greedy-dist", "2.0000", "1.0000"]
    assert out[3][:2] == ["cso", "-"] and out[3][2].startswith("1.1000 (+10.0 % [")


def test_benchmarks_tables_1_and_2_are_what_the_printed_command_pools_from_the_committed_episodes():
    """BENCHMARKS.md's pooling block, run as printed (bash, from the repository), gives Table 1's rows as the file
    has them, and with ``--table2`` Table 2's (the same files): the command names every committed folder the tables
    come from, and the tables are not stale."""
    import re
    import subprocess
    import sys

    root = Path(__file__).parents[1]
    text = (root / "BENCHMARKS.md").read_text(encoding="utf-8")
    section = text[text.index("## Table 1") : text.index("## The learned CSO policy")]
    block = re.search(r"^    R=benchmarks/results\n(?:    .*\n)+", section, flags=re.MULTILINE)
    assert block is not None, "Table 1's pooling command is gone"
    script = "\n".join(line[4:] for line in block.group(0).splitlines())
    table2 = script.splitlines()[-1].replace("benchmarks/tables.py", "benchmarks/tables.py --table2", 1)
    r = subprocess.run(["bash", "-c", f'python() {{ "{sys.executable}" "$@"; }}\nset -e\n{script}\necho TABLE2\n{table2}'], cwd=root, capture_output=True, text=True, timeout=300, env={"PATH": "/usr/bin:/bin", "PYTHONPATH": str(root)})
    assert r.returncode == 0, r.stderr[-2000:]
    table1_out, table2_out = r.stdout.split("TABLE2\n")
    table_row = re.compile(r"^\| (?:small|middle|large|super_large) \| .*$", flags=re.MULTILINE)
    printed = table_row.findall(section.split("How the episodes ended")[0])
    assert len(printed) == 40, "Table 1 lost rows"
    assert table_row.findall(table1_out) == printed
    method_row = re.compile(r"^\| (?:greedy|utility|random|cso|gnn)[\w-]* \| .*$", flags=re.MULTILINE)
    table2_section = text[text.index("### Table 2") : text.index("With the paper's 2 m bound")]
    assert len(method_row.findall(table2_section)) == 10, "Table 2 lost rows"
    assert method_row.findall(table2_out) == method_row.findall(table2_section)


def test_a_cut_episodes_csv_among_several_is_named_in_one_line(tmp_path, capsys):
    """``tables.py a.csv b.csv`` with one of them cut short ended in a ValueError traceback, "line 4 has 6 cells ...",
    naming no file; it is a usage error (exit 2) naming the file, as compare names it."""
    whole = write(tmp_path / "whole.csv", [episode("greedy-dist", m, "large", 1.0) for m in "abc"])
    text = whole.read_text()
    cut = tmp_path / "cut.csv"
    cut.write_text(text[: text.rindex("99.5") + 2])
    tables = load_tables()
    with pytest.raises(ValueError, match=f"^{re.escape(str(cut))}: line 4 has 6 cells"):
        tables.pooled_rows([("", whole), ("", cut)])
    for extra in ([], ["--table2"]):
        with pytest.raises(SystemExit) as exited:
            tables.main([str(whole), str(cut), *extra])
        assert exited.value.code == 2
        err = capsys.readouterr().err
        assert f"{cut}: line 4 has 6 cells" in err and "Traceback" not in err, err


def test_a_plan_of_one_name_at_two_cell_sizes_is_two_plans_in_table_1_as_in_its_paired_cell(tmp_path, capsys):
    """``easy=A_0.05 easy=A_0.1`` (BENCHMARKS.md pools so): a plan of one name at two cell sizes has two traversable
    areas, two scenes to compare. Table 1 kept one episode of the two where both fell in one scale (a small PNG plan):
    the later file's replaced the earlier's, Table 1 counted half the episodes while ``compare`` paired all of them."""
    def at(cell_m: float, method: str, map_: str, efficiency: float) -> dict:
        return {**episode(method, map_, "small", efficiency), "traversable_area_m2": 16.0 if cell_m == 0.1 else 4.0, "cell_size_m": cell_m}

    coarse = write(tmp_path / "coarse.csv", [at(0.1, m, p, e) for m, e in (("greedy-dist", 1.0), ("cso", 1.1)) for p in "abc"])
    fine = write(tmp_path / "fine.csv", [at(0.05, m, p, e) for m, e in (("greedy-dist", 0.5), ("cso", 0.6)) for p in "abc"])
    tables = load_tables()
    assert tables.main([f"easy={coarse}", f"easy={fine}"]) == 0
    rows = {(c[0], c[1]): c for c in map(cells, capsys.readouterr().out.splitlines()[2:])}
    assert rows[("small", "greedy-dist")][2] == "6" and rows[("small", "greedy-dist")][6] == f"{0.75:.4f}"
    assert rows[("small", "cso")][2] == "6" and rows[("small", "cso")][9].endswith("], 6 won")
    # Its 95 % interval resamples six plans, not three plans of two episodes each.
    import numpy as np

    from cso_runtime.comparison import bootstrap_mean_ci

    pooled = tables.pool([("easy", coarse), ("easy", fine)], "greedy-dist")
    expected = bootstrap_mean_ci(np.array([1.0, 0.5, 1.0, 0.5, 1.0, 0.5]))
    assert pooled.by_scale[("greedy-dist", "small")]["efficiency_m2_per_step_ci95"] == pytest.approx(list(expected), abs=1e-6)


def test_a_summary_json_that_does_not_read_is_one_line_naming_it_not_a_traceback(tmp_path, capsys):
    """An episodes.csv cut short was one line naming it; a summary.json cut short (or of another shape) was a
    JSONDecodeError traceback, after the table's header had been printed."""
    cut = tmp_path / "summary.json"
    cut.write_text('{"methods": {"greedy-dist": {"by_sc')
    tables = load_tables()
    with pytest.raises(SystemExit) as ended:
        tables.main([str(cut)])
    said = capsys.readouterr()
    assert ended.value.code == 2 and f"{cut}: not a summary.json eval wrote (JSONDecodeError" in said.err and said.out == "", said
    cut.write_text('{"methods": []}')
    with pytest.raises(SystemExit):
        tables.main([str(cut)])
    assert f"{cut}: not a summary.json eval wrote (AttributeError" in capsys.readouterr().err


def test_files_of_no_episode_are_one_line_saying_so_not_a_table_of_headers_alone(tmp_path, capsys):
    """An episodes.csv of its header alone (an eval stopped before its first episode) printed Table 1's header and
    exited 0, as did a summary.json of no method: a table of nothing, taken for a run that compared nothing. Now one
    line in compare's words, with compare's exit code for it (1: the files read and hold nothing; it was 2 here, a
    usage error, where compare says 1)."""
    empty = write(tmp_path / "empty.csv", [])
    assert empty.read_text().strip() == ",".join(CSV_FIELDS)
    none = tmp_path / "summary.json"
    none.write_text('{"methods": {}}')
    tables = load_tables()
    for args in ([str(empty)], ["--table2", str(empty)], [f"easy={empty}", f"medium={empty}"], [str(none)]):
        with pytest.raises(SystemExit) as ended:
            tables.main(args)
        said = capsys.readouterr()
        assert ended.value.code == 1 and said.out == "", (args, said)
        assert f"error: these files hold no episode: {args[-1].partition('=')[2] or args[-1]}" in said.err, (args, said.err)
    # One file of no episode beside one with episodes pools the other's, as compare does.
    full = write(tmp_path / "full.csv", [episode("greedy-dist", "a", "large", 1.0)])
    assert tables.main([str(empty), str(full)]) == 0
    assert "| large | greedy-dist | 1 |" in capsys.readouterr().out


def test_tables_warns_of_plans_run_under_other_setups_as_compare_does(tmp_path, capsys):
    """Table 1's paired cells pair episodes as ``compare`` does, but a 360-degree LiDAR's eval pooled with a 180-degree
    one's was tabled without compare's warning; now the same warnings (``comparison.mixed_setups_said``) go to stderr,
    and a plan of one name at two cell sizes (two traversable areas, never paired) is not warned of."""
    def run(name: str, method: str, fov: float, cell_m: float = 0.05, area: float = 150.0) -> Path:
        return write(tmp_path / f"{name}.csv", [
            {**episode(method, m, "large", 1.0), "sensor_fov_deg": fov, "sim": "2d", "cell_size_m": cell_m, "max_steps": 300, "traversable_area_m2": area}
            for m in "abc"
        ])

    base, ring = run("base", "greedy-dist", 180.0), run("ring", "cso", 360.0)
    tables = load_tables()
    for extra in ([], ["--table2"]):
        assert tables.main([*extra, str(base), str(ring)]) == 0
        said = capsys.readouterr()
        assert f"warning: the same plans ran with different sensor_fov_deg: 180 ({base}), 360 ({ring}) on 3 plans (a, b, c)" in said.err, said.err
        assert "cso" in said.out
    coarse = write(tmp_path / "coarse.csv", [{**r, "traversable_area_m2": 16.0, "cell_size_m": 0.1} for r in map(dict, _rows(base))])
    assert tables.main([f"easy={base}", f"easy={coarse}"]) == 0
    assert capsys.readouterr().err == ""


def _rows(path: Path) -> list[dict]:
    import csv

    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


def test_a_baseline_of_no_episode_is_refused_as_compare_refuses_it(tmp_path, capsys):
    """``--baseline greedy-dsit`` (a typo) printed Table 1 with every row's paired column empty and exited 0, a table
    that read as one of methods sharing no scene with the baseline; compare refuses it (exit 2, naming the methods the
    files hold). Now tables.py does too, in either layout."""
    import subprocess
    import sys

    full = write(tmp_path / "full.csv", [episode(m, s, "large", 1.0) for m in ("greedy-dist", "cso") for s in "abc"])
    tables = load_tables()
    for extra in ([], ["--table2"]):
        with pytest.raises(SystemExit) as ended:
            tables.main([*extra, "--baseline", "greedy-dsit", str(full)])
        said = capsys.readouterr()
        assert ended.value.code == 2 and said.out == "", said
        assert "error: --baseline 'greedy-dsit' has no episodes in these files; their methods: cso, greedy-dist" in said.err, said.err
    compare = subprocess.run([sys.executable, "-m", "cso_runtime.cli", "compare", str(full), "--baseline", "greedy-dsit"], capture_output=True, text=True, timeout=60)
    assert compare.returncode == 2 and "--baseline 'greedy-dsit' has no episodes in these files; their methods: cso, greedy-dist" in compare.stderr, compare.stderr
    assert tables.main([str(full)]) == 0
