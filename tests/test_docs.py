"""The documentation stays true: docs/paper-to-code.md's references and defaults, and every command and flag the
README, BENCHMARKS.md and docs/ show."""

from __future__ import annotations

import dataclasses
import importlib
import math
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


def test_the_node_feature_row_names_every_node_feature():
    """The row on the paper's node features named the optional ``size`` but not ``unknown`` (``unknown_area_feature``,
    a field of configs/train.yaml since the feature came): every column a graph may have is named there."""
    from cso_runtime.learned.graph import GraphConfig, node_features

    row = next(line for line in _doc().splitlines() if line.startswith("| node features"))
    columns = node_features(GraphConfig(use_cluster_size=True, use_unknown_area=True))
    assert len(columns) >= 8 and [c for c in columns if f"`{c}`" not in row] == []


def test_the_training_config_names_every_field_with_its_default():
    """docs/training.md says configs/train.yaml documents every field: each ``Args`` field but the flags of one run is in
    it, and nothing else is."""
    from cso_runtime.learned.ppo import Args

    train = yaml.safe_load((ROOT / "configs" / "train.yaml").read_text(encoding="utf-8"))
    fields = {f.name for f in dataclasses.fields(Args)}
    assert sorted(fields - set(train)) == ["init_from", "progress", "resume"]  # flags of one run, not of a recipe
    assert set(train) <= fields


SHORT_COMMAND = re.compile(r"^([a-z][a-z-]* [^`\n]*--[^`\n]*)$")
"""A code span that starts with a command's name and has a flag: ``up --dry-run``."""
FLAG = re.compile(r"(?<![\w-])(--[a-z][a-z0-9-]*)")
PYTHON_COMMAND = re.compile(r"python3? (?:-m ([\w.]+)|(benchmarks/\w+\.py))(.*?)(?: && |; |$)")
"""``python -m MODULE ARGS`` or ``python benchmarks/SCRIPT.py ARGS``."""
DECLARED_FLAG = re.compile(r"add_argument\(\s*\"(--[\w-]+)\"")


def _declared_flags(*sources: Path) -> set[str]:
    """The ``--flags`` that argparse parsers in these files declare."""
    return {"--help"} | {f for src in sources for f in DECLARED_FLAG.findall(src.read_text(encoding="utf-8"))}


def _service_flags(name: str) -> set[str]:
    """The ``--flags`` of ``cso-runtime service NAME``, a built-in service: its parser's (the common options, its own,
    and those it takes from a shared definition, as the foxglove bridge's frames from ``frame_names``)."""
    from services import command_service_class
    from services.common import service_parser

    return set(service_parser(name, command_service_class(name))._option_string_actions)


def test_every_command_and_flag_the_docs_show_exists():
    """Every ``cso-runtime`` command and flag; every service's own flag (``service NAME --port``, ``python -m
    services.NAME``); every ``python benchmarks/SCRIPT.py`` and ``python -m`` module of the project, and their flags."""
    cli = typer.main.get_command(app)
    options = {name: {o for p in c.params for o in (*p.opts, *p.secondary_opts)} | {"--help"} for name, c in cli.commands.items()}
    global_options = {o for p in cli.params for o in p.opts}
    service_flags = _declared_flags(ROOT / "services" / "common.py")
    wrong, seen = [], 0
    for doc in DOCS:
        code = _code(doc)
        spans = [m for line in code for m in DOCUMENTED_COMMAND.findall(line)]
        spans += [s for line in code for s in SHORT_COMMAND.findall(line) if s.split()[0] in options]
        for span in spans:
            seen += 1
            command, line = span.split()[0], span.split("#")[0]
            flags = set(FLAG.findall(line))
            if command not in options:
                wrong.append(f"{doc.name}: no command {command!r} ({span[:60]})")
            elif command == "service" and (ROOT / "services" / f"{line.split()[1:2] and line.split()[1]}.py").is_file():
                own = _service_flags(line.split()[1])
                wrong += [f"{doc.name}: service {line.split()[1]} has no {flag}" for flag in sorted(flags - own)]
            elif command == "service" and ":" in line.split()[1:2][0]:  # a service of one's own: the common flags
                wrong += [f"{doc.name}: service {line.split()[1]} has no {flag}" for flag in sorted(flags - service_flags)]
            elif command != "service":
                wrong += [f"{doc.name}: {command} has no {flag}" for flag in sorted(flags - options[command] - global_options)]
        for module, script, args in (m for line in code for m in PYTHON_COMMAND.findall(line)):
            if module.split(".")[0] not in ("services", "robot_sim", "cso_runtime", "benchmarks") and not script:
                continue  # another package's (mujoco.viewer, pstats)
            seen += 1
            path = ROOT / (script or module.replace(".", "/") + ".py")
            if module and not path.is_file():  # a package run as a module: its __main__.py (python -m services NAME)
                path = ROOT / module.replace(".", "/") / "__main__.py"
            if not path.is_file():
                wrong.append(f"{doc.name}: no {path.relative_to(ROOT)} (python {script or '-m ' + module})")
                continue
            declared = _declared_flags(path, *([ROOT / "services" / "common.py"] if module.split(".")[0] == "services" else []))
            wrong += [f"{doc.name}: {path.relative_to(ROOT)} has no {flag}" for flag in sorted(set(FLAG.findall(args.split("#")[0])) - declared)]
    assert seen >= 120, "the docs lost their examples, or the pattern broke"
    assert wrong == []


DOCS = [ROOT / "README.md", ROOT / "BENCHMARKS.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "configs" / "profiles" / "README.md"]
"""What users read for commands (docs/experiments/ is a record of what was tried, kept as it was)."""
READ_FIRST = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
"""The README and the reference pages it leads to (docs/), where a fact the README once held now is."""
TRAINING_DOC = ROOT / "docs" / "training.md"
"""The learned policy's page: the training log's columns and the Gymnasium environment (the README's until it became a
front page)."""
DOCUMENTED_COMMAND = re.compile(r"cso-runtime ([a-z].*?)(?: && |; |$)")
PLACEHOLDERS = {"path/to/dungeon": "../shared/maps/dungeon", "METHODS": "all", "SET": "easy", "DEV": "../shared/maps/dungeon/train", "SCENES": "builtin", "NAME": "sim"}
"""What BENCHMARKS.md's upper-case words stand for in a command (``DEV``: a development set of training plans; the
profiles' README's ``up --profile NAME``: a profile's name)."""


def _shown_files(doc: Path) -> dict[str, str]:
    """File name -> text of each code block of ``doc`` that starts with a comment naming it (``# own.yaml: ...``): a
    file the page shows whole and its commands then use (``up --profile own.yaml``)."""
    blocks = re.findall(r"^ *```[^\n]*\n(.*?)^ *```", doc.read_text(encoding="utf-8"), flags=re.DOTALL | re.MULTILINE)
    return {m.group(1): block for block in blocks if (m := re.match(r"# ([\w.-]+\.\w+):", block))}


def _code(doc: Path) -> list[str]:
    """Every code line (fenced or indented block) and inline code span of a Markdown file, a span wrapped over two
    lines and a command continued with ``\\`` joined again."""
    text = doc.read_text(encoding="utf-8").replace("\\\n", " ")
    lines = re.findall(r"^ *```[^\n]*\n(.*?)^ *```", text, flags=re.DOTALL | re.MULTILINE)
    text = re.sub(r"^ *```.*?^ *```", "", text, flags=re.DOTALL | re.MULTILINE)
    indented = [line for line in text.splitlines() if line.startswith("    ") and "`" not in line]
    lines = [line for block in lines for line in block.splitlines()] + indented
    text = "\n".join(line for line in text.splitlines() if line not in indented)
    return lines + [span.replace("\n", " ") for span in re.findall(r"`([^`]+)`", text)]


def _documented_commands() -> list[tuple[str, str]]:
    """``(doc, "CMD ARGS")`` for every ``cso-runtime CMD ARGS`` the docs show."""
    return [(str(doc.relative_to(ROOT)), m) for doc in DOCS for line in _code(doc) for m in DOCUMENTED_COMMAND.findall(line)]


def _variants(command: str) -> list[list[str]]:
    """The argument lists a documented command stands for: every ``[--optional part]`` given, its ``a | b``
    alternatives and every ``a|b`` value in turn (so each alternative is tried), placeholders filled in."""
    import shlex

    command = command.split(" #")[0].replace("\\", " ").replace("...", " ")
    for word, value in PLACEHOLDERS.items():
        command = re.sub(rf"\b{re.escape(word)}\b", value, command)
    groups = re.findall(r"(?<= )\[(--[^\]]*)\]", command)
    alternatives = [group.split(" | ") for group in groups]
    variants = []
    count = max([len(a) for a in alternatives] + [len(t.split("|")) for t in command.replace(" | ", "|").split()])
    for i in range(count):
        text = command
        for group, alts in zip(groups, alternatives):
            text = text.replace(f"[{group}]", alts[i % len(alts)], 1)
        tokens = shlex.split(text.replace(" | ", "|"))
        variants.append([t.split("|")[i % len(t.split("|"))] for t in tokens])
    return variants


class _Validated(Exception):
    """Raised in place of the work a command would start, once it has accepted its arguments."""


def test_every_run_eval_and_train_command_the_docs_show_is_accepted(tmp_path, monkeypatch):
    """Each documented ``up``, ``eval``, ``train`` and ``collect-teacher`` command passes the command's own checks
    (``up --dry-run``; the others up to their first episode): its profile, methods, variant, scenes, config files,
    ``--set`` keys and flags together. BENCHMARKS.md showed ``eval ... [--sensor depth] [--lidar-fov 360]``, two
    flags that ``eval`` refuses together. Run as on the build machine: from the repository, the Dungeon sets in
    ``../shared/maps/dungeon`` (one plan each here); a folder that one documented command writes and another reads
    (``train --out runs/train/cso``, ``collect-teacher --out``) is made as that command would."""
    import shutil

    import numpy as np
    from typer.testing import CliRunner

    import robot_sim.viewer
    import services.foxglove_bridge
    from cso_runtime import cli, evaluation
    from cso_runtime.learned import ppo
    from cso_runtime.learned.graph import empty_graph
    from cso_runtime.scenes import builtin_scene_dir
    from tests.conftest import unset_weights_env

    def stop(*args, **kwargs):
        raise _Validated

    def collected(args, *rest, **kwargs):  # one decision of the configuration's layout, as the workers would give
        graph = {k: np.asarray(v)[None] for k, v in empty_graph(args.env_config().graph).items()}
        mask = np.ones((1, args.max_frontier_nodes), dtype=bool)
        return ppo.TeacherData(graph, mask, np.zeros(1, np.int64), np.zeros(1, np.float32), np.full((1, args.max_frontier_nodes), np.inf))

    monkeypatch.setattr(evaluation, "run_eval", stop)
    monkeypatch.setattr(ppo, "train", stop)
    monkeypatch.setattr(ppo, "collect_teacher_parallel", collected)
    monkeypatch.setattr(cli, "interrupt_on_sigterm", lambda **_kwargs: None)  # train passes wait_on_second=True
    monkeypatch.setattr(robot_sim.viewer, "display_problem", lambda *a, **k: None)  # no display here
    monkeypatch.setattr(services.foxglove_bridge, "port_problem", lambda *a, **k: None)  # nor a free port 8765 in CI
    repo = tmp_path / "repo"
    repo.mkdir()
    for plans in ("train", "easy", "medium", "complex"):
        (tmp_path / "shared" / "maps" / "dungeon" / plans).mkdir(parents=True)
        shutil.copy(builtin_scene_dir() / "img_1.png", tmp_path / "shared" / "maps" / "dungeon" / plans)
    monkeypatch.chdir(repo)
    unset_weights_env(monkeypatch)  # restored after the test, whatever `--weights` set in between
    commands = [(doc, argv) for doc, command in _documented_commands() for argv in _variants(command)]
    outs = {argv[argv.index("--out") + 1] for _, argv in commands if argv[0] == "train" and "--out" in argv}
    wrong, checked = [], 0
    for doc, argv in commands:
        if argv[0] not in ("up", "eval", "train", "collect-teacher"):
            continue
        argv = [str(ROOT / a) if "/" in a and not a.startswith(("/", "..")) and (ROOT / a).exists() else a for a in argv]
        unset_weights_env(monkeypatch)  # as a new shell: an earlier --weights set one
        trained = Path(argv[argv.index("--weights") + 1]) if "--weights" in argv else None
        if trained is not None and not any(trained.glob("*.pt")):  # a training run's folder, as `train` leaves it
            assert str(trained) in outs, f"{doc}: --weights {trained}: no documented `train --out` writes it"
            trained.mkdir(parents=True, exist_ok=True)
            shutil.copy(ROOT / "cso_runtime" / "data" / "weights" / "cso.pt", trained)
        if "--profile" in argv and not (profile := Path(argv[argv.index("--profile") + 1])).exists():
            shown = _shown_files(ROOT / doc)
            if profile.name in shown:  # a profile the page shows whole (docs/own-service.md's own.yaml)
                profile.write_text(shown[profile.name])
        if "--zenoh-config" in argv and not (zenoh_config := Path(argv[argv.index("--zenoh-config") + 1])).exists():
            zenoh_config.write_text("{}")  # the user's own Zenoh config file (its examples: test_the_zenoh_config_examples...)
        r = CliRunner().invoke(app, [*argv, "--dry-run"] if argv[0] == "up" and "--dry-run" not in argv else argv)
        checked += 1
        if not (r.exit_code == 0 if argv[0] in ("up", "collect-teacher") else isinstance(r.exception, _Validated)):
            wrong.append(f"{doc}: cso-runtime {' '.join(argv)}: {(r.output or repr(r.exception)).strip()[-300:]}")
    assert checked >= 50, "the docs lost their commands, or the pattern broke"
    assert wrong == []


REPO_PATH = re.compile(r"(?<![\w/.$-])((?:benchmarks/)?results/[\w{},.*/@<>-]+|(?:cso_runtime|configs|docs|services|robot_sim|benchmarks|tests)/[\w{},.*/@<>-]+)")
"""A path in the repository: ``configs/train.yaml``, ``results/footprint_stall/{dev180,l180}_*`` (BENCHMARKS.md's
``results/`` is ``benchmarks/results/``)."""


def _expand_braces(path: str) -> list[str]:
    """``a/{b,c}_d`` -> ``a/b_d``, ``a/c_d`` (the shell's brace expansion)."""
    group = re.search(r"\{([^{}]*)\}", path)
    if group is None:
        return [path]
    return [p for alt in group.group(1).split(",") for p in _expand_braces(path[: group.start()] + alt + path[group.end() :])]


def test_every_repository_path_the_docs_name_exists():
    """A results folder, config, module or test a doc points to is there (globs and ``{a,b}`` as the shell reads
    them); ``<run-id>``-style placeholders are left out."""
    import glob

    missing, seen = [], 0
    for doc in DOCS:
        for ref in REPO_PATH.findall(doc.read_text(encoding="utf-8")):
            ref = ref.rstrip(".,)/")
            if "<" in ref or (ref.startswith("results/") and doc.name != "BENCHMARKS.md"):
                continue  # a placeholder, or an output folder of a command (docs/eval.md's `--out results/easy`)
            for path in _expand_braces("benchmarks/" + ref if ref.startswith("results/") else ref):
                seen += 1
                if not glob.glob(str(ROOT / path)):
                    missing.append(f"{doc.name}: {path}")
    assert seen >= 200, "the docs lost their references, or the pattern broke"
    assert missing == []


def test_the_readmes_python_example_runs_and_prints_an_episode(tmp_path):
    """The "From Python" block, run as a user would paste it: one episode, its Table 1 figures printed."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-c", python_examples()[0]], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    coverage, steps, efficiency = re.fullmatch(r"(\d+\.\d) % in (\d+) steps, (\d\.\d{3}) m2/step\n", r.stdout).groups()
    assert float(coverage) > 99.0 and int(steps) > 0 and float(efficiency) > 0


PYTHON_EXAMPLES = [ROOT / "docs" / "eval.md", ROOT / "docs" / "simulator.md", ROOT / "docs" / "training.md"]
"""The pages with the ```python blocks that were the README's: the "From Python" episode, the MuJoCo LIMO on its own,
then the shipped weights in the Gymnasium env."""


def python_examples() -> list[str]:
    """The ```python block of each page of ``PYTHON_EXAMPLES``, in that order: one a page."""
    blocks = [re.findall(r"```python\n(.*?)```", doc.read_text(encoding="utf-8"), flags=re.DOTALL) for doc in PYTHON_EXAMPLES]
    assert [len(b) for b in blocks] == [1, 1, 1], "the docs' Python examples are gone"
    return [b[0] for b in blocks]


EVAL_DOC = ROOT / "docs" / "eval.md"
"""The page of ``eval``'s outputs: its table of the files of a results folder (the README's until it became a front page)."""


def _eval_output_rows() -> dict[str, str]:
    """File name (as the table quotes it, in backticks) -> its row of docs/eval.md's table of outputs."""
    return {line.split("|")[1].strip(): line for line in EVAL_DOC.read_text(encoding="utf-8").splitlines() if line.startswith("| `")}


def test_the_readmes_mujoco_example_steps_the_limo_and_writes_a_world_mujoco_loads(tmp_path):
    """The MuJoCo LIMO block, as pasted: it drives, prints its odometry and LiDAR, and its world.xml loads in MuJoCo
    with the LIMO at the start pose (what ``python -m mujoco.viewer --mjcf world.xml`` opens)."""
    import subprocess
    import sys

    import mujoco

    r = subprocess.run([sys.executable, "-c", python_examples()[1]], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert re.fullmatch(r"odom x -?\d+\.\d\d m, y -?\d+\.\d\d m, yaw 0\.\d\d rad; 181 beams\n", r.stdout), r.stdout
    model = mujoco.MjModel.from_xml_path(str(tmp_path / "world.xml"))
    assert model.opt.timestep == 0.005 and model.nu == 3
    assert list(model.qpos0) == list(model.key("start").qpos)  # the viewer opens it, and Reset goes back, to the start


def test_the_readmes_gymnasium_example_runs_the_shipped_weights_in_the_default_env(tmp_path):
    """The training environment's block, as pasted: the shipped weights fit ``gymnasium.make``'s default graph."""
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-c", python_examples()[2]], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    returns = [float(x) for x in re.fullmatch(r"\[(.*)\]\n", r.stdout).group(1).split(",")]
    assert len(returns) == 2 and all(math.isfinite(x) for x in returns)


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
    """A user reading a results folder finds each column of episodes.csv and paired.csv and each per-method key of
    summary.json in the table of outputs (docs/eval.md; with its unit), not only in the code."""
    from cso_runtime.evaluation import CSV_FIELDS, METRICS, summarize

    rows = _eval_output_rows()
    csv_row, summary_row = rows["`episodes.csv`"], rows["`summary.json`"]
    assert [c for c in CSV_FIELDS if f"`{c}`" not in csv_row] == []
    from cso_runtime.comparison import CSV_FIELDS as PAIRED_FIELDS

    assert [c for c in PAIRED_FIELDS if f"`{c}`" not in rows["`paired.csv`"]] == []
    row = {"method": "m", "map": "a", "scale": "small", "seed": 0, "terminated_by": "coverage", **dict.fromkeys(METRICS, 1.0)}
    entry = summarize([row], [], ["m"], meta={})["methods"]["m"]
    assert [k for k in entry if f"`{k}`" not in summary_row] == []
    assert [k for k in ("request", "version", "config", "sim_settings", "mujoco", "weights") if f"`{k}`" not in summary_row] == []  # meta's
    assert [k for k in summarize([row], [], ["m"], meta={}) if f"`{k}`" not in summary_row] == []  # its top-level keys


def test_the_readme_says_which_image_an_interrupted_runs_last_map_has():
    """The README said an interrupted run keeps ``last_map.yaml`` and ``.png`` "as ``save-map`` writes it", but
    ``save-map`` writes PGM by default: it names the image the launcher writes and the ``save-map`` command that
    writes the same."""
    from cso_runtime.launcher import LAST_MAP, LAST_MAP_IMAGE_FORMAT

    readme = " ".join(" ".join(doc.read_text(encoding="utf-8").split()) for doc in READ_FIRST)  # a sentence may wrap
    image = Path(LAST_MAP).with_suffix(f".{LAST_MAP_IMAGE_FORMAT}").name
    assert f"`{LAST_MAP}` and `{image}`" in readme and f"`save-map --format {LAST_MAP_IMAGE_FORMAT}`" in readme


def test_the_readmes_summary_json_row_names_every_key_of_meta(tmp_path):
    """``meta`` in a real eval's ``summary.json`` held ``command``, ``maps`` (the ``--maps`` spec, not the per-method
    ``maps``), ``seed``, ``scenes`` and, with ``--resume``, ``resumed_episodes``, which the README's row did not name;
    nor ``paused_s``, which ``up`` writes. Each key of ``meta`` is named in the row's part on ``meta``."""
    import json

    from cso_runtime.evaluation import EvalRequest, run_eval

    run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:0", out_dir=tmp_path, max_steps=5, resume=True))
    meta = json.loads((tmp_path / "summary.json").read_text(encoding="utf-8"))["meta"]
    assert {"request", "config", "resumed_episodes"} <= set(meta)
    others = {"interrupted", "weights", "mujoco", "profile", "paused_s", "episode", "lost_results"}  # Ctrl-C, a learned method, --sim-config; up's
    rows = _eval_output_rows()
    about_meta = rows["`summary.json`"].split("`meta` (", 1)[1]
    assert sorted(k for k in {*meta, *others} if f"`{k}`" not in about_meta) == []


MERMAID_EDGE = re.compile(r"^\s*(\w+)\s*-->\|\"?([^|\"]+)\"?\|\s*(\w+)", flags=re.MULTILINE)


def _mermaid_edges(text: str) -> set[tuple[str, str, str]]:
    """``(from, key, to)`` of each ``a -->|k1, k2| b`` line of a mermaid flowchart."""
    return {(a, key.strip(), b) for a, keys, b in MERMAID_EDGE.findall(text) for key in keys.split(",")}


def test_the_readmes_dataflow_graph_is_part_of_the_sim_profiles():
    """README's graph of ``up --profile sim`` leaves keys out (it says ``dataflow --format mermaid`` prints them all),
    but each arrow it draws is one the code declares."""
    from typer.testing import CliRunner

    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    drawn = _mermaid_edges(re.search(r"```mermaid\n(.*?)```", readme, flags=re.DOTALL).group(1))
    r = CliRunner().invoke(app, ["dataflow", "--profile", "sim", "--format", "mermaid"])
    assert r.exit_code == 0, r.output
    assert len(drawn) >= 12 and sorted(drawn - _mermaid_edges(r.output)) == []


MAIN_JOB = "python3 -m venv .venv && . .venv/bin/activate && pip install -c constraints.txt -e . && cso-runtime up --profile sim"
"""The README's main job, word for word (the set-up .ci/run repeats with the test extra)."""


def test_the_readme_is_a_front_page_with_the_two_commands_and_a_line_for_every_command():
    """README.md is a front page, the reference in docs/: its "Two commands" are exactly the main job and CI's
    ``bash .ci/run``, its table of commands gives every command of the CLI a line and a link to the page that documents
    it, it links every page of docs/, and it stays short enough to read through."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    two = readme.split("\n## Two commands\n", 1)[1].split("\n## ", 1)[0]
    assert re.findall(r"```bash\n(.*?)\n```", two, flags=re.DOTALL) == [MAIN_JOB, "bash .ci/run"]
    table = readme.split("\n## Commands\n", 1)[1].split("\n## ", 1)[0]
    rows = [line.split("|") for line in table.splitlines() if line.startswith("| `")]
    named = {name for row in rows for name in re.findall(r"`([\w-]+)`", row[1])}
    assert sorted(set(typer.main.get_command(app).commands) - named) == []
    assert [row[1] for row in rows if not MARKDOWN_LINK.search(row[3])] == []
    linked = set(MARKDOWN_LINK.findall(readme))
    assert sorted(f"docs/{doc.name}" for doc in (ROOT / "docs").glob("*.md") if f"docs/{doc.name}" not in linked) == []
    assert len(readme.splitlines()) < 300, "the README grew back into a reference: move the details to docs/"


def test_the_readme_names_every_array_of_an_episodes_npz(tmp_path):
    """``episodes/<method>/<map>.npz`` holds more than the three arrays the README's table named (the row, and the
    fingerprints ``--resume`` matches): a user loading one with numpy finds each of its keys there."""
    import numpy as np

    from cso_runtime.evaluation import EvalRequest, run_eval
    from cso_runtime.outputs import episode_npz_path

    run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:0", out_dir=tmp_path, max_steps=5))
    rows = _eval_output_rows()
    keys = np.load(episode_npz_path(tmp_path, "greedy-dist", "gen_small_0")).files
    assert len(keys) >= 3 and [k for k in keys if f"`{k}`" not in rows["`episodes/<method>/<map>.npz`"]] == []


def test_a_training_commands_refusal_names_only_flags_it_has(tmp_path):
    """``train`` and ``collect-teacher`` name the flags that changed the recipe in their errors (``configs/train.yaml
    with --variant x: ...``); ``collect-teacher --teacher x`` was quoted as ``--warm-start-teacher x``, a flag no
    command has, so the user could not find what to change."""
    from typer.testing import CliRunner

    cli = typer.main.get_command(app)
    refused = {
        "collect-teacher": ["--out", str(tmp_path / "t.npz"), "--teacher", "oracle", "--seed", "3", "--dungeon-dir", str(tmp_path)],
        "train": ["--variant", "cso-x", "--seed", "3", "--num-envs", "2", "--sync-envs", "--time-limit-s", "5", "--dungeon-dir", str(tmp_path)],
    }
    for command, argv in refused.items():
        r = CliRunner().invoke(app, [command, *argv])
        assert r.exit_code == 2, r.output
        error = r.output.split("error:", 1)[1]
        options = {o for p in cli.commands[command].params for o in (*p.opts, *p.secondary_opts)}
        named = FLAG.findall(error.split(":")[0])  # "FILE with --flag value ...: why"
        assert named and set(named) <= options, f"{command}'s error names {set(named) - options}: {error}"


def test_the_zenoh_config_examples_of_hardware_md_are_files_zenoh_and_the_runtime_accept(tmp_path):
    """Every JSON5 block of "Securing the network" reads as a Zenoh config the runtime takes as a base; the files
    it names are made empty here (certificates are not checked by reading the config)."""
    from cso_runtime.transport import FILE_KEYS, load_zenoh_config_file

    section = (ROOT / "docs" / "hardware.md").read_text(encoding="utf-8").split("## 9. Securing the network", 1)[1]
    blocks = re.findall(r"```json5\n(.*?)```", section, re.DOTALL)
    assert len(blocks) >= 4  # user/password (laptop, robot), TLS, access control
    for i, block in enumerate(blocks):
        for named in re.findall(r'"(/[^"]+)"', block):  # the example's absolute paths, moved under tmp_path
            moved = tmp_path / named.lstrip("/")
            moved.parent.mkdir(parents=True, exist_ok=True)
            moved.touch()
            block = block.replace(f'"{named}"', f'"{moved}"')
        path = tmp_path / f"example{i}.json5"
        path.write_text(block)
        load_zenoh_config_file(path)
    assert any(key.rsplit("/", 1)[1] in section for key in FILE_KEYS)


def test_every_commands_help_reads_whole_on_an_80_column_terminal():
    """``up --help`` on a plain terminal cut the second ``--set`` example to ``exploration.episode.max_steps=4…``:
    rich ellipsizes a word longer than its column, so every command's help is written in words that wrap."""
    from typer.testing import CliRunner

    cli = typer.main.get_command(app)
    for name in cli.commands:
        r = CliRunner().invoke(app, [name, "--help"], terminal_width=80, env={"COLUMNS": "80"})
        assert r.exit_code == 0 and "…" not in r.output, f"{name} --help:\n{r.output}"


BRACKETED = re.compile(r"\\?\[[^\]\n]*\]")
"""Square-bracketed text in a help string (escaped for rich as ``\\[...]`` or not)."""


def test_every_commands_help_shows_its_bracketed_text():
    """``down --help`` showed ``--timeout-s`` without its ``[default: three times the run's ...]``: typer renders help
    as rich markup, in which ``[word ...]`` is a style tag and vanishes unless escaped (``\\[``)."""
    from typer.testing import CliRunner

    cli = typer.main.get_command(app)
    checked, lost = [], []
    for name, command in cli.commands.items():
        texts = [command.help or "", *(getattr(p, "help", None) or "" for p in command.params)]
        wanted = [" ".join(m.replace("\\[", "[").split()) for text in texts for m in BRACKETED.findall(text)]
        if wanted:
            r = CliRunner().invoke(app, [name, "--help"], terminal_width=1000, env={"COLUMNS": "1000"})
            shown = " ".join(r.output.replace("\u2502", " ").split())  # the box's side, where a long line wraps
            checked += [f"{name}: {w}" for w in wanted]
            lost += [f"{name}: {w}" for w in wanted if w not in shown]
    assert "down: [default: three times the run's supervision.stop_timeout_s, plus 10 s]" in checked
    assert lost == []


def test_the_readme_names_every_info_key_of_the_training_environment():
    """A Gymnasium user reads ``info`` for the episode's figures: the README's paragraph on the environment named the
    action mask, the plan and the invalid actions, not the coverage, steps, explored area, how the episode ended or the
    control steps a decision took (``decision_steps``, what a semi-MDP discount needs), which ``step`` also gives."""
    import numpy as np

    from cso_runtime.learned.env import make_env

    readme = TRAINING_DOC.read_text(encoding="utf-8")
    paragraph = readme[readme.index("**The training environment**") :].split("\n\n")[0]
    env = make_env("generated:small:1:0")
    _, reset_info = env.reset(seed=0)
    allowed = np.flatnonzero(reset_info["action_mask"])
    _, _, _, _, step_info = env.step(int(allowed[0]))
    masked = np.flatnonzero(step_info["action_mask"] == 0)
    _, _, _, _, rejected_info = env.step(int(masked[0]))
    keys = {*reset_info, *step_info, *rejected_info}
    assert sorted(k for k in keys if f'info["{k}"]' not in paragraph) == []


def test_the_readme_names_every_column_of_the_training_log_with_its_unit():
    """A CleanRL user plots ``<variant>_log.csv``: the README only pointed at ``ppo.LOG_FIELDS`` in the code, which
    names no unit (is ``wall_s`` this process's time, ``entropy`` in nats, ``env_steps`` decisions or control steps?).
    Its paragraph on the log now names each column with what it counts."""
    from cso_runtime.learned.ppo import LOG_FIELDS

    readme = TRAINING_DOC.read_text(encoding="utf-8")
    paragraph = " ".join(readme[readme.index("**The CSV log**") :].split("\n- ")[0].split())  # its lines joined
    assert [c for c in LOG_FIELDS if f"`{c}` (" not in paragraph] == []


def test_the_readme_names_the_training_logs_columns_in_the_files_order():
    """A newcomer reads the CSV log's paragraph as the file's header: it named ``mean_episode_steps`` beside
    ``mean_return``, while the file has it (added later) after ``explained_variance``."""
    from cso_runtime.learned.ppo import LOG_FIELDS

    readme = TRAINING_DOC.read_text(encoding="utf-8")
    paragraph = " ".join(readme[readme.index("**The CSV log**") :].split("\n- ")[0].split())
    named = sorted(LOG_FIELDS, key=lambda column: paragraph.index(f"`{column}` ("))
    assert named == LOG_FIELDS


def test_the_readme_says_which_scale_the_training_environment_gives_png_plans():
    """``make_env``'s ``m_per_px`` (0.05, Dungeon's large scale) is not ``eval --m-per-px``'s (0.1, super large), and
    the README's paragraph on the environment named the parameter without saying which it takes."""
    import inspect

    from cso_runtime.learned.env import make_env

    readme = TRAINING_DOC.read_text(encoding="utf-8")
    paragraph = readme[readme.index("**The training environment**") :].split("\n\n")[0]
    env_default = inspect.signature(make_env).parameters["m_per_px"].default
    eval_default = next(p.default for p in typer.main.get_command(app).commands["eval"].params if p.name == "m_per_px")
    assert env_default != eval_default  # the reason to say it
    assert f"`m_per_px`, the scale of PNG plans in metres per pixel, is {env_default:g} unless given" in paragraph
    assert f"`eval --m-per-px` is {eval_default:g}" in paragraph


def test_hardware_mds_defaults_are_the_codes():
    """docs/hardware.md quotes defaults a ROS user compares with Nav2's and sets on the robot: the controller table's
    Default column (``exploration.``) and the bridge's parameters (``Ros2BridgeParams``); each is the code's."""
    from services.ros2_bridge import Ros2BridgeParams

    text = (ROOT / "docs" / "hardware.md").read_text(encoding="utf-8")
    exploration = dataclasses.asdict(ExplorationConfig())
    rows = re.findall(r"^\| ((?:`(?:planner|episode|robot)\.\w+`(?:, )?)+) \| ([^|]+) \|", text, flags=re.MULTILINE)
    assert len(rows) >= 8, "the table lost its rows, or the pattern broke"
    wrong = []
    for keys, values in rows:
        numbers = [float(v.split()[0]) for v in values.split(", ")]
        for key, number in zip(re.findall(r"`(\w+)\.(\w+)`", keys), numbers, strict=True):
            if exploration[key[0]][key[1]] != number:
                wrong.append(f"{'.'.join(key)}: the table says {number}, the default is {exploration[key[0]][key[1]]}")
    bridge = text.split("The bridge's parameters", 1)[1].split("\n\n", 1)[0]
    quoted = re.findall(r"`(\w+)` \((-?\d+(?:\.\d+)?)", bridge)
    assert len(quoted) >= 12, "the bridge's parameters lost their defaults, or the pattern broke"
    defaults = dataclasses.asdict(Ros2BridgeParams())
    wrong += [f"{key}: the doc says {text}, the default is {defaults[key]}" for key, text in quoted if defaults[key] != float(text)]
    assert wrong == []


def test_the_zenoh_config_flag_names_every_command_that_opens_a_session():
    """``cso-runtime --zenoh-config`` and docs/hardware.md named ``status``, ``save-map``, ``record``, ``replay``,
    ``service`` and ``up`` as the commands it applies to, and the first four as those that take the current run's own
    file; ``pause`` and ``resume`` open the same sessions (``--connect``, the run file's endpoints and config) and were
    left out. Every command with ``--connect`` opens a session; those that also read a runs folder's current run take
    its file."""
    cli = typer.main.get_command(app)

    def options(name: str) -> set[str]:
        return {o for p in cli.commands[name].params for o in p.opts}

    opening = {name for name in cli.commands if "--connect" in options(name)} | {"service"}  # service: its own argparse flags
    of_the_run = {name for name in opening - {"service", "up"} if "--runs-dir" in options(name)}
    assert {"status", "pause", "record"} <= of_the_run
    flag_help = next(p.help or "" for p in cli.params if "--zenoh-config" in p.opts)
    assert sorted(opening - set(re.findall(r"[\w-]+", flag_help))) == []
    text = " ".join((ROOT / "docs" / "hardware.md").read_text(encoding="utf-8").split())
    where = text.split("**Where it applies**", 1)[1].split("\n- ", 1)[0]
    sessions = re.search(r"any command that opens a session \(([^)]*)\)", where)
    own = re.search(r"\); ([^;.]*) of the current run take the run's own file", where)
    assert sessions is not None and own is not None, "the paragraph changed: update this test"
    assert set(re.findall(r"`([\w-]+)`", sessions.group(1))) == opening
    assert set(re.findall(r"`([\w-]+)`", own.group(1))) == of_the_run
    runtime = " ".join((ROOT / "docs" / "runtime.md").read_text(encoding="utf-8").split())
    said = re.search(r"gives it to any other command, and ([^.]*) of the current run take the run's own", runtime)
    assert said is not None and set(re.findall(r"`([\w-]+)`", said.group(1))) == of_the_run


def _bridge_counters() -> set[str]:
    """The counters the ROS 2 bridge shows in ``status`` (``services.ros2_bridge.counters``) under a name of their own:
    ``self.counters["NAME"]``, ``count_and_warn_once("NAME", ...)``, ``_new_episode(why, "NAME")`` and the drops of
    ``count_reject("topic:reason", ...)`` (counted as ``dropped:topic:reason``, said as ``topic:reason``)."""
    import ast

    names = set()
    for node in ast.walk(ast.parse((ROOT / "services" / "ros2_bridge.py").read_text(encoding="utf-8"))):
        if isinstance(node, ast.Subscript) and isinstance(node.value, ast.Attribute) and node.value.attr == "counters":
            if isinstance(node.slice, ast.Constant):
                names.add(node.slice.value)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            index = {"count_and_warn_once": 0, "count_reject": 0, "_new_episode": 1}.get(node.func.attr)
            if index is not None and len(node.args) > index and isinstance(node.args[index], ast.Constant):
                names.add(node.args[index].value)
    return names


def test_hardware_md_names_every_counter_and_drop_reason_of_the_bridge():
    """A ROS user reads the bridge's counters in ``status`` and looks them up in docs/hardware.md: ``ros_scan:invalid``,
    ``ros_resume:bad_cdr``, ``received:resume`` and ``scans_with_invalid_beams`` were counted but named nowhere."""
    names = _bridge_counters()
    assert {"ros_scan:bad_cdr", "watchdog_stops", "odometry_resets"} <= names, "the pattern broke"
    text = (ROOT / "docs" / "hardware.md").read_text(encoding="utf-8")
    assert sorted(n for n in names if f"`{n}`" not in text) == []


MARKDOWN_LINK = re.compile(r"\]\(([^)\s]+)\)")


def _anchors(doc: Path) -> set[str]:
    """The anchors GitHub gives the headings of ``doc`` (lower case, punctuation dropped, spaces as ``-``)."""
    text = re.sub(r"^ *```.*?^ *```", "", doc.read_text(encoding="utf-8"), flags=re.DOTALL | re.MULTILINE)
    return {re.sub(r"[^\w\- ]", "", h.strip().lower()).replace(" ", "-") for h in re.findall(r"^#+ (.*)$", text, flags=re.MULTILINE)}


def test_every_relative_link_of_the_docs_resolves():
    """A ``[text](path#anchor)`` link between the docs leads to a file that is there and a heading it has."""
    wrong, seen = [], 0
    for doc in DOCS:
        for target in MARKDOWN_LINK.findall(doc.read_text(encoding="utf-8")):
            if target.startswith(("http://", "https://", "mailto:")):
                continue
            seen += 1
            path, _, anchor = target.partition("#")
            linked = (doc.parent / path).resolve() if path else doc
            if not linked.exists():
                wrong.append(f"{doc.name}: {target}: no such file")
            elif anchor and linked.suffix == ".md" and anchor not in _anchors(linked):
                wrong.append(f"{doc.name}: {target}: no such heading")
    assert seen >= 20, "the docs lost their links, or the pattern broke"
    assert wrong == []


STATUS_JSON_PATHS = {"services.ros2_bridge.counters", "services.ros2_bridge.robot_stops"}
"""Dotted names the docs give that are ``status --json`` paths, not profile keys."""
PROFILE_KEY = re.compile(
    r"`((?:exploration\.\w+|supervision|router|services\.\w+(?:\.mujoco)?)\.(?!(?:py|md|yaml|log)`)\w+)`(?: \((-?\d+(?:\.\d+)?|true|false)\b)?"
)
"""A profile key the docs name in full, with the value in brackets after it when they give one: ``supervision.X``,
``router.X``, ``exploration.SECTION.X``, ``services.SERVICE.X``, ``services.sim.mujoco.X`` (not a file:
``supervision.py``)."""


def _profile_keys() -> dict[str, list[object]]:
    """Every key of a profile -> its default and the values the shipped profiles give it."""
    from cso_runtime.run_profile import RouterConfig, SupervisionConfig
    from robot_sim.config import MujocoSimConfig
    from services import COMMAND_NODE_KEYS, OWN_CLASS_KEY, SERVICE_NAMES, params_class

    def defaults(cls: type) -> dict[str, object]:
        return dataclasses.asdict(cls()) if dataclasses.is_dataclass(cls) else {}

    keys: dict[str, list[object]] = {}
    sections = {"supervision": SupervisionConfig, "router": RouterConfig, "services.sim.mujoco": MujocoSimConfig}
    sections |= {f"exploration.{f.name}": type(getattr(ExplorationConfig(), f.name)) for f in dataclasses.fields(ExplorationConfig)}
    sections |= {f"services.{name}": params_class(name) for name in SERVICE_NAMES if params_class(name) is not None}
    for section, cls in sections.items():
        keys |= {f"{section}.{key}": [value] for key, value in defaults(cls).items()}
        if section.count(".") == 1 and section.startswith("services."):
            keys |= {f"{section}.{key}": [] for key in (OWN_CLASS_KEY, *COMMAND_NODE_KEYS)}

    def flatten(prefix: str, node: object) -> None:
        if isinstance(node, dict):
            for key, value in node.items():
                flatten(f"{prefix}.{key}" if prefix else str(key), value)
        elif prefix in keys:
            keys[prefix].append(node)

    for profile in sorted((ROOT / "configs" / "profiles").glob("*.yaml")):
        flatten("", yaml.safe_load(profile.read_text(encoding="utf-8")))
    return keys


def test_every_profile_key_the_docs_name_exists_and_its_value_is_a_default_or_a_shipped_profiles():
    """A key a doc names in full (``supervision.hang_timeout_s``, ``services.frontier.helper_start_s``) is one a profile
    takes, and the value in brackets after it (``(20 s``) is its default, or the one a shipped profile gives it
    (``services.planner.stale_after_s`` (1 s in limo-ros2)); the help of every command is held to the same."""
    keys = _profile_keys()
    cli = typer.main.get_command(app)
    texts = {str(doc.relative_to(ROOT)): doc.read_text(encoding="utf-8") for doc in DOCS}
    for name, command in [("cso-runtime", cli), *cli.commands.items()]:  # the help texts, whose keys are not in backticks
        shown = " ".join([command.help or "", *(getattr(p, "help", None) or "" for p in command.params)])
        texts[f"{name} --help"] = re.sub(r"(?<![\w`])((?:exploration\.\w+|supervision|router|services\.\w+)\.\w+)", r"`\1`", shown)
    wrong, seen = [], 0
    for where, text in texts.items():
        for key, value in PROFILE_KEY.findall(text):
            if key in STATUS_JSON_PATHS or (key.startswith("services.") and key.split(".")[1] not in {k.split(".")[1] for k in keys if k.startswith("services.")}):
                continue  # a service of one's own (services.coverage_logger.every_steps), or a module (services.common.X)
            seen += 1
            if key not in keys:
                wrong.append(f"{where}: no profile key {key}")
            elif value:
                number = {"true": True, "false": False}.get(value, value)
                if not any(v == number if isinstance(number, bool) else isinstance(v, (int, float)) and float(v) == float(number) for v in keys[key]):
                    wrong.append(f"{where}: {key} ({value}: the default and the shipped profiles give {keys[key]})")
    assert seen >= 60, "the docs lost their keys, or the pattern broke"
    assert wrong == []


def test_runtime_mds_several_robots_names_every_command_that_picks_a_run():
    """docs/runtime.md, Several robots, said that ``status``, ``save-map``, ``record``, ``logs`` and ``down`` take
    ``--runs-dir`` and the first three ``--robot``; ``replay``, ``pause`` and ``resume`` take them too. The commands that
    pick a run of a runs folder are those with ``--runs-dir`` but ``up`` (it makes one), ``runs`` (it lists them) and
    ``doctor``; of them, those with ``--robot`` also ask for a robot."""
    cli = typer.main.get_command(app)
    options = {name: {o for p in c.params for o in p.opts} for name, c in cli.commands.items()}
    picking = {name for name, opts in options.items() if "--runs-dir" in opts} - {"up", "runs", "doctor"}
    asking = {name for name in picking if "--robot" in options[name]}
    text = " ".join((ROOT / "docs" / "runtime.md").read_text(encoding="utf-8").split())
    runs_dir = re.search(r"([^.]*) take `--runs-dir` to pick the run; ([^.(]*) also take `--robot`", text)
    assert runs_dir is not None, "the sentence changed: update this test"
    assert set(re.findall(r"`([\w-]+)`", runs_dir.group(1))) == picking
    assert set(re.findall(r"`([\w-]+)`", runs_dir.group(2))) == asking


def test_the_readmes_exit_code_table_says_what_record_and_replay_do_with_no_run(tmp_path, monkeypatch):
    """``record`` (and ``replay``) with no current run and no ``--connect`` exit 2 (no router to record from or replay
    into), which the README's table of exit codes left out: its row 1 lists "nothing is running" for status, save-map
    and down alone, so a script could not tell which code to expect."""
    from typer.testing import CliRunner

    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(app, ["record", "--out", str(tmp_path / "new.mcap")])
    assert r.exit_code == 2 and "no current run" in r.output, r.output
    row = next(line for line in (ROOT / "docs" / "commands.md").read_text(encoding="utf-8").splitlines() if line.startswith("| 2 |"))
    assert "no current run and no `--connect` (`record`, `replay`" in row


def test_the_readmes_dry_run_and_resolved_bullet_names_the_commands_that_have_them():
    """The README's Configs section said "``--dry-run`` checks everything ..." of every command, after naming ``train``'s
    ``--set``: ``train --dry-run`` is "no such option". The bullet names the commands that take ``--dry-run`` and
    ``--resolved``, and those alone."""
    readme = " ".join((ROOT / "README.md").read_text(encoding="utf-8").split())
    bullet = readme.split("- **`--dry-run`** (", 1)[1].split(")", 1)[0]
    named = set(re.findall(r"`([\w-]+)`", bullet))
    cli = typer.main.get_command(app)
    for flag in ("--dry-run", "--resolved"):
        having = {name for name, c in cli.commands.items() if any(flag in p.opts for p in c.params)}
        assert having == named, f"{flag}: the README names {sorted(named)}, the commands that have it are {sorted(having)}"


def test_every_file_the_readmes_layout_table_names_is_in_its_folder():
    """The Layout table names modules by their file name alone (``occupancy.py`` on the ``cso_runtime/`` row), which
    the check of repository paths does not see: each is a file of its row's folder."""
    layout = (ROOT / "README.md").read_text(encoding="utf-8").split("\n## Layout\n", 1)[1].split("\n## ", 1)[0]
    missing, seen = [], 0
    for line in layout.splitlines():
        if row := re.match(r"\| `([\w/]+)/`", line):
            for name in re.findall(r"`(\w+\.py)`", line):
                seen += 1
                if not (ROOT / row.group(1) / name).is_file():
                    missing.append(f"{row.group(1)}/{name}")
    assert seen >= 30, "the Layout table lost its modules, or the pattern broke"
    assert missing == []


def test_the_table_of_evals_outputs_names_every_file_an_eval_writes_and_each_is_written(tmp_path):
    """docs/eval.md's table of outputs is where a user looks up a file of a results folder: each file (pattern) it
    names is one that an eval writes (with ``--animate``, and the baseline beside another method on 3 plans, as
    ``paired.csv`` needs), and each file the eval writes is in the table."""
    import fnmatch

    from cso_runtime.evaluation import EvalRequest, run_eval

    patterns = []
    for name in _eval_output_rows():
        for part in re.findall(r"`([^`]+)`", name):
            part = f"{patterns[-1].rsplit('.', 1)[0]}{part}" if part.startswith(".") else part  # `a/b.yaml`, `.png`
            patterns.append(re.sub(r"<[^>]+>", "*", part))
    run_eval(EvalRequest(methods=["greedy-dist", "random"], maps="generated:small:3:0", out_dir=tmp_path, max_steps=5, animate=True))
    written = [str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*") if p.is_file() and not p.name.startswith(".")]
    assert len(patterns) >= 12, patterns
    assert [p for p in patterns if not fnmatch.filter(written, p)] == [], "the table names files an eval does not write"
    assert [w for w in written if not any(fnmatch.fnmatch(w, p) for p in patterns)] == [], "an eval writes files the table does not name"
