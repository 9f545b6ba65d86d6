"""The documentation stays true: docs/paper-to-code.md's references and defaults, and every command and flag the
README, BENCHMARKS.md and docs/ show."""

from __future__ import annotations

import dataclasses
import importlib
import re
from pathlib import Path

import typer
import yaml

from cso_runtime.cli import app
from cso_runtime.config import ExplorationConfig
from cso_runtime.learned.network import NetworkConfig
from cso_runtime.messages import MESSAGE_TYPES

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "paper-to-code.md"
CODE_REF = re.compile(r"`([a-z_][\w.]*):([A-Za-z_]\w*)`")
FILE_REF = re.compile(r"`((?:cso_runtime|configs|docs|services|robot_sim|benchmarks)/[\w/.-]+\.(?:py|yaml|md))`")
MODULE_REF = re.compile(r"`((?:cso_runtime|robot_sim|services)(?:\.\w+)+)`")
DEFAULT_REF = re.compile(r"`([a-z_][a-z_0-9]*(?:\.[a-z_0-9]+)?)` \((-?\d+(?:\.\d+)?|true|false)\b")


def _doc() -> str:
    return DOC.read_text(encoding="utf-8")


def test_every_code_reference_resolves():
    refs = CODE_REF.findall(_doc())
    assert len(refs) >= 30, "the table lost its references"
    missing = []
    for module, name in refs:
        if not hasattr(importlib.import_module(module), name):
            missing.append(f"{module}:{name}")
    assert missing == []
    for module in MODULE_REF.findall(_doc()):
        importlib.import_module(module)
    for path in FILE_REF.findall(_doc()):
        assert (ROOT / path).is_file(), path


def _default_of(key: str, train: dict) -> object:
    if "." in key:
        section, field = key.split(".")
        return getattr(getattr(ExplorationConfig(), section), field)
    if key in train:
        return train[key]
    return {f.name: f.default for f in dataclasses.fields(NetworkConfig)}[key]


def test_every_quoted_default_is_the_default():
    train = yaml.safe_load((ROOT / "configs" / "train.yaml").read_text(encoding="utf-8"))
    quoted = DEFAULT_REF.findall(_doc())
    assert len(quoted) >= 25, "the table lost its defaults"
    wrong = []
    for key, text in quoted:
        value = {"true": True, "false": False}.get(text, None)
        actual = _default_of(key, train)
        if value is None:
            value = float(text)
            actual = float(actual)  # type: ignore[arg-type]
        if actual != value:
            wrong.append(f"{key}: the doc says {text}, the default is {actual}")
    assert wrong == []


def test_the_training_config_names_every_field_with_its_default():
    """README says configs/train.yaml documents every field: each ``Args`` field but the flags of one run is in
    it, and nothing else is."""
    from cso_runtime.learned.ppo import Args

    train = yaml.safe_load((ROOT / "configs" / "train.yaml").read_text(encoding="utf-8"))
    fields = {f.name for f in dataclasses.fields(Args)}
    assert sorted(fields - set(train)) == ["init_from", "progress", "resume"]  # flags of one run, not of a recipe
    assert set(train) <= fields


COMMAND_LINE = re.compile(r"cso-runtime ([a-z][^`\n]*)")
"""``cso-runtime CMD ...`` up to the end of the code span or line."""
SHORT_COMMAND = re.compile(r"`([a-z][a-z-]* [^`\n]*--[^`\n]*)`")
"""A code span that starts with a command's name and has a flag: ``up --dry-run``."""
FLAG = re.compile(r"(?<![\w-])(--[a-z][a-z0-9-]*)")


def test_every_command_and_flag_the_docs_show_exists():
    cli = typer.main.get_command(app)
    options = {name: {o for p in c.params for o in (*p.opts, *p.secondary_opts)} | {"--help"} for name, c in cli.commands.items()}
    global_options = {o for p in cli.params for o in p.opts}
    wrong, seen = [], 0
    for doc in [ROOT / "README.md", ROOT / "BENCHMARKS.md", *sorted((ROOT / "docs").glob("*.md"))]:
        text = doc.read_text(encoding="utf-8")
        spans = COMMAND_LINE.findall(text) + [s for s in SHORT_COMMAND.findall(text) if s.split()[0] in options]
        for span in spans:
            seen += 1
            command, line = span.split()[0], span.split("#")[0]
            if command not in options:
                wrong.append(f"{doc.name}: no command {command!r} ({span[:60]})")
            elif command != "service":  # a service's own flags pass through to it
                wrong += [f"{doc.name}: {command} has no {flag}" for flag in FLAG.findall(line) if flag not in options[command] | global_options]
    assert seen >= 80, "the docs lost their examples, or the pattern broke"
    assert wrong == []


def test_the_readmes_python_example_runs_and_prints_an_episode(tmp_path):
    """The "From Python" block, run as a user would paste it: one episode, its Table 1 figures printed."""
    import subprocess
    import sys

    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(encoding="utf-8"), flags=re.DOTALL)
    assert len(blocks) == 1, "README's Python example is gone"
    r = subprocess.run([sys.executable, "-c", blocks[0]], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    coverage, steps, efficiency = re.fullmatch(r"(\d+\.\d) % in (\d+) steps, (\d\.\d{3}) m2/step\n", r.stdout).groups()
    assert float(coverage) > 99.0 and int(steps) > 0 and float(efficiency) > 0


def test_messages_md_states_each_schemas_wire_version():
    """docs/messages.md's version paragraph is the one table users read: a schema whose ``VERSION`` moved without
    it (``frontiers`` was documented at 7 while the code still sent 6) misleads anyone writing a bridge."""
    text = (ROOT / "docs" / "messages.md").read_text(encoding="utf-8")
    paragraph = text[text.index("Each schema has its own version") :].split("\n\n", 1)[0]
    documented: dict[str, int] = {}
    # "`a`, `b` and `c` (2: ..." names several schemas at one version; "`frontiers` (7: ..." one.
    for names, version in re.findall(r"((?:`\w+`(?:, | and )?)+) \((\d+):", paragraph):
        for name in re.findall(r"`(\w+)`", names):
            documented[name] = int(version)
    assert len(documented) >= 8, f"the paragraph lost its versions: {documented}"
    assert set(documented) <= set(MESSAGE_TYPES), f"documented schemas that do not exist: {set(documented) - set(MESSAGE_TYPES)}"
    actual = {schema: cls.VERSION for schema, cls in MESSAGE_TYPES.items()}
    assert {s: documented.get(s, 1) for s in actual} == actual


def test_the_readme_names_every_column_of_episodes_csv_and_every_key_of_summary_json():
    """A user reading a results folder finds each column of episodes.csv and each per-method key of summary.json
    in the README's table of outputs (with its unit), not only in the code."""
    from cso_runtime.evaluation import CSV_FIELDS, METRICS, summarize

    rows = {line.split("|")[1].strip(): line for line in (ROOT / "README.md").read_text(encoding="utf-8").splitlines() if line.startswith("| `")}
    csv_row, summary_row = rows["`episodes.csv`"], rows["`summary.json`"]
    assert [c for c in CSV_FIELDS if f"`{c}`" not in csv_row] == []
    row = {"method": "m", "map": "a", "scale": "small", "seed": 0, "terminated_by": "coverage", **dict.fromkeys(METRICS, 1.0)}
    entry = summarize([row], [], ["m"], meta={})["methods"]["m"]
    assert [k for k in entry if f"`{k}`" not in summary_row] == []
    assert [k for k in ("request", "version", "config", "sim_settings", "mujoco", "weights") if f"`{k}`" not in summary_row] == []  # meta's
