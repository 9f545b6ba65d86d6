"""What software produced a results file (``cso_runtime.provenance``): the record eval's ``summary.json``, ``up``'s run
folder and ``train``'s ``<variant>.json`` keep, and ``cso-runtime --version``."""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import cso_runtime
from cso_runtime import provenance
from cso_runtime.provenance import git_checkout, software_provenance

ROOT = Path(__file__).resolve().parents[1]
FROM_A_CHECKOUT = (ROOT / ".git").exists() and shutil.which("git") is not None


def _head() -> str:
    return subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()


def test_the_record_names_the_package_its_checkouts_commit_python_and_the_libraries():
    record = software_provenance()
    assert record["version"] == cso_runtime.__version__ and record["python"] == ".".join(map(str, sys.version_info[:3]))
    assert record["packages"]["numpy"] == np.__version__ and set(record["packages"]) == {"numpy", "torch", "mujoco"}
    if FROM_A_CHECKOUT:
        assert record["git_commit"] == _head() and isinstance(record["git_modified"], bool)
    json.dumps(record)  # a results file's JSON


def test_no_commit_is_recorded_without_a_checkout_of_its_own_or_without_git(tmp_path: Path, monkeypatch):
    """An installed wheel has no ``.git`` beside the package (its site-packages may be inside another repository, whose
    commit is not the package's); where git is missing or fails, the commit is left out and nothing fails."""
    outer = tmp_path / "outer"
    (outer / "site-packages").mkdir(parents=True)
    if shutil.which("git") is not None:
        subprocess.run(["git", "init", "-q", str(outer)], check=True)
    assert git_checkout(outer / "site-packages") is None  # no .git of its own
    (outer / "site-packages" / ".git").write_text("gitdir: /nowhere\n")  # a broken worktree link
    assert git_checkout(outer / "site-packages") is None
    if FROM_A_CHECKOUT:
        git_checkout.cache_clear()
        monkeypatch.setenv("PATH", str(tmp_path / "no-git-here"))
        try:
            assert git_checkout(ROOT) is None and "git_commit" not in software_provenance()
        finally:
            git_checkout.cache_clear()


def test_version_prints_the_commit_of_a_checkout_on_a_second_line(monkeypatch):
    """``cso-runtime --version``'s first line stays ``cso-runtime X.Y.Z`` (a contract); from a checkout, its commit follows."""
    from typer.testing import CliRunner

    from cso_runtime.cli import app

    lines = CliRunner().invoke(app, ["--version"]).output.splitlines()
    assert lines[0] == f"cso-runtime {cso_runtime.__version__}"
    if FROM_A_CHECKOUT:
        assert lines[1].startswith(f"git commit {_head()}") and len(lines) == 2
    monkeypatch.setattr(provenance, "git_checkout", lambda root=None: None)  # an installed wheel
    assert CliRunner().invoke(app, ["--version"]).output == f"cso-runtime {cso_runtime.__version__}\n"


def test_evals_summary_records_the_software_and_the_command_line_that_ran_it(tmp_path: Path):
    """``summary.json`` had the package version and the flags, not the commit, Python, libraries or the command line."""
    out = tmp_path / "o"
    args = ["eval", "--method", "greedy-dist", "--maps", "generated:small:1:0", "--max-steps", "4", "--out", str(out)]
    done = subprocess.run([sys.executable, "-m", "cso_runtime.cli", *args], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    software = json.loads((out / "summary.json").read_text())["meta"]["software"]
    assert software["command_line"] == " ".join(["cso-runtime", *args])
    assert {k: software[k] for k in ("version", "python", "packages")} == {k: software_provenance()[k] for k in ("version", "python", "packages")}
    if FROM_A_CHECKOUT:
        assert software["git_commit"] == _head()


def test_a_detached_up_hands_its_command_line_to_the_launcher(tmp_path: Path, monkeypatch):
    """The launcher of ``up --detach`` is a process of its own: the command line of ``up`` reaches it as an argument."""
    from cso_runtime import launcher
    from cso_runtime.run_profile import find_profile, load_profile

    started: list[list[str]] = []

    class NoLauncher:
        def __init__(self, argv: list[str], **kwargs: object) -> None:
            started.append(argv)
            self.stdin, self.returncode, self.pid = io.BytesIO(), 2, 0  # refused at once, as a launcher may be

        def poll(self) -> int:
            return self.returncode

    monkeypatch.setattr(launcher.subprocess, "Popen", NoLauncher)
    monkeypatch.setattr(provenance, "_command_line", "cso-runtime up --detach --profile lockstep")
    profile, data = load_profile(str(find_profile("lockstep")), {})
    code, _ = launcher.start_detached(profile, data, tmp_path / "runs")
    (argv,) = started
    assert code == 2 and argv[argv.index("--command-line") + 1] == "cso-runtime up --detach --profile lockstep"


def test_the_readme_names_every_key_of_the_software_record():
    """A researcher reading ``summary.json`` finds ``meta.software`` and each of its keys in the table of outputs
    (docs/eval.md, the README's until it became a front page)."""
    rows = {line.split("|")[1].strip(): line for line in (ROOT / "docs" / "eval.md").read_text(encoding="utf-8").splitlines() if line.startswith("| `")}
    keys = ["software", "git_commit", "git_modified", "command_line", *software_provenance(), *software_provenance()["packages"]]
    assert [k for k in keys if f"`{k}`" not in rows["`summary.json`"] and k not in rows["`summary.json`"]] == []


def test_the_report_header_names_the_commit_that_made_the_table():
    """report.html's header line said the package version only: two checkouts of one version made different tables."""
    from cso_runtime.report import run_settings_text

    meta = {"command": "cso-runtime eval", "version": "0.1.0", "software": {"git_commit": "0123456789abcdef0123", "git_modified": True}, "seed": 0}
    assert run_settings_text(meta).startswith("command: cso-runtime eval, version: 0.1.0, commit: 0123456789ab (modified), seed: 0")
    assert "commit" not in run_settings_text({**meta, "software": {"version": "0.1.0"}})  # an installed package: none


def _repo(path: Path, commits: int = 1) -> str:
    """A git repository at ``path`` with one file and ``commits`` commits; its HEAD."""
    git = ["git", "-C", str(path), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run(["git", "init", "-q", str(path)], check=True)
    (path / "f.txt").write_text("a\n")
    subprocess.run([*git, "add", "f.txt"], check=True)
    for n in range(commits):
        subprocess.run([*git, "commit", "-q", "--allow-empty", "-m", f"commit {n}"], check=True)
    return subprocess.run([*git, "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_the_commit_is_read_without_writing_the_checkouts_index(tmp_path: Path):
    """``git status`` refreshes the index where a file's stat changed, under ``.git/index.lock``: each eval rewrote the
    user's index, and a ``git commit`` run meanwhile could fail on the lock. The record is read without optional locks."""
    commit = _repo(tmp_path)
    index = tmp_path / ".git" / "index"
    later_ns = index.stat().st_mtime_ns + 2_000_000_000
    os.utime(tmp_path / "f.txt", ns=(later_ns, later_ns))  # touched, not changed: a refresh would rewrite the index
    before = index.stat().st_mtime_ns, index.read_bytes()
    git_checkout.cache_clear()
    assert git_checkout(tmp_path) == {"git_commit": commit, "git_modified": False}
    assert (index.stat().st_mtime_ns, index.read_bytes()) == before


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_the_commit_is_the_packages_checkouts_under_a_git_hooks_environment(tmp_path: Path, monkeypatch):
    """Run from a git hook (a pre-commit that runs the tests) or ``git rebase --exec``, ``GIT_DIR`` and ``GIT_INDEX_FILE``
    may name another repository: the record named that one's commit as the package's checkout's."""
    commit = _repo(tmp_path / "package")
    _repo(other := tmp_path / "other", commits=2)
    monkeypatch.setenv("GIT_DIR", str(other / ".git"))
    monkeypatch.setenv("GIT_INDEX_FILE", str(other / ".git" / "index"))
    git_checkout.cache_clear()
    assert git_checkout(tmp_path / "package") == {"git_commit": commit, "git_modified": False}


def test_evals_record_names_the_commit_that_ran_the_episodes_not_the_one_checked_out_at_the_end(tmp_path: Path, monkeypatch):
    """The record was taken as the summary was written, after every episode: an eval of hours while its checkout was
    switched to another branch (or committed to) named the commit checked out at the end, not the code that ran."""
    from cso_runtime import evaluation
    from cso_runtime.evaluation import EvalRequest, run_eval

    checked_out = {"git_commit": "the commit that runs the episodes"}
    run_job = evaluation.run_job

    def checkout_switched_meanwhile(job: evaluation.EpisodeJob) -> evaluation.EpisodeOutcome:
        checked_out["git_commit"] = "a commit checked out while they ran"
        return run_job(job)

    monkeypatch.setattr(evaluation, "software_provenance", lambda: dict(checked_out))
    monkeypatch.setattr(evaluation, "run_job", checkout_switched_meanwhile)
    summary = run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:0", out_dir=tmp_path, max_steps=4))
    assert summary["meta"]["software"] == {"git_commit": "the commit that runs the episodes"}


def test_the_report_header_names_the_commit_beside_the_version_of_a_summary_without_a_command():
    """The commit went in at a fixed place, third where ``version`` was a key: a summary without ``command`` (or with a
    null ``version``) had it after the maps, or before the version."""
    from cso_runtime.report import run_settings_text

    software = {"git_commit": "0123456789abcdef0123"}
    assert run_settings_text({"version": "0.1.0", "maps": "generated:small:1:0", "software": software}).startswith("version: 0.1.0, commit: 0123456789ab, maps")
    assert run_settings_text({"command": "cso-runtime eval", "version": None, "seed": 0, "software": software}).startswith("command: cso-runtime eval, commit: 0123456789ab, seed")
