"""Files another command or a resume reads are written whole or not at all (``outputs.write_whole``): a write
stopped midway (Ctrl-C, a signal, a full disk) leaves the earlier file as it was, and no partial file beside it.

Each test cuts the low-level write short (half a file, then KeyboardInterrupt, as a Ctrl-C in the middle of it)
and checks the earlier file and the folder's listing."""

from __future__ import annotations

import csv
import json
import pathlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cso_runtime.geometry import GridGeometry


def cut_short(write: Callable[..., Any]) -> Callable[..., Any]:
    """``write(target, ...)`` that writes its file, leaves half of it and is interrupted."""

    def cut(*args: Any, **kwargs: Any) -> None:
        target = args[1] if len(args) > 1 and isinstance(args[1], str | Path) else args[0]
        write(*args, **kwargs)
        if isinstance(target, str | Path):
            data = Path(target).read_bytes()
            Path(target).write_bytes(data[: len(data) // 2])
        else:  # an open file
            target.flush()
            target.truncate(max(target.tell() // 2, 1))
        raise KeyboardInterrupt

    return cut


def cut_text_writes_short(monkeypatch: pytest.MonkeyPatch) -> None:
    real = pathlib.Path.write_text

    def cut(self: Path, data: str, *args: Any, **kwargs: Any) -> int:
        real(self, data[: len(data) // 2], *args, **kwargs)
        raise KeyboardInterrupt

    monkeypatch.setattr(pathlib.Path, "write_text", cut)


def listing(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def assert_stopped_write_keeps(folder: Path, write: Callable[[], Any]) -> None:
    before = listing(folder)
    assert before
    with pytest.raises(KeyboardInterrupt):
        write()
    assert listing(folder) == before  # the earlier files, byte for byte, and no partial file left


def test_train_record_json_stopped_while_written_keeps_the_earlier_one(tmp_path, monkeypatch):
    """``<variant>.json`` (what ``eval --weights`` reads: the sensor and masks the weights were trained with) was
    written in place beside its whole ``.pt``: a stop while it was written left half a JSON."""
    from cso_runtime.learned.network import GraphActorCritic, NetworkConfig
    from cso_runtime.learned.ppo import Args, save_weights

    model, args = GraphActorCritic(NetworkConfig()), Args()
    save_weights(tmp_path, model, args, {"ppo_decisions": 10})
    assert json.loads((tmp_path / f"{args.variant}.json").read_text())["ppo_decisions"] == 10
    cut_text_writes_short(monkeypatch)
    before = (tmp_path / f"{args.variant}.json").read_bytes()
    with pytest.raises(KeyboardInterrupt):
        save_weights(tmp_path, model, args, {"ppo_decisions": 20})
    assert (tmp_path / f"{args.variant}.json").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"{args.variant}.json", f"{args.variant}.pt"]


def test_teacher_data_stopped_while_written_keeps_the_earlier_file(tmp_path, monkeypatch):
    """``teacher_data.npz`` (``train``'s, ``collect-teacher``'s; ``--warm-start-data`` reads it) was written in place."""
    from cso_runtime.learned.ppo import TeacherData

    data = TeacherData(graphs={"x": np.zeros((2, 3), np.float32)}, masks=np.ones((2, 4), bool), actions=np.zeros(2, np.int64), returns=np.zeros(2), outcome_steps=np.zeros((2, 4)))
    data.save(tmp_path / "teacher_data.npz")
    monkeypatch.setattr(np, "savez_compressed", cut_short(np.savez_compressed))
    assert_stopped_write_keeps(tmp_path, lambda: data.save(tmp_path / "teacher_data.npz"))


@pytest.mark.parametrize("image_format", ["png", "pgm"])
def test_map_files_stopped_while_written_keep_the_earlier_ones(tmp_path, monkeypatch, image_format):
    """``save-map``'s and eval's / up's ``maps/`` map_server files (YAML and image) were written in place."""
    from PIL import Image

    from cso_runtime.map_files import load_map, save_map

    geometry = GridGeometry(0.05, (4, 6))
    grid = np.zeros((4, 6), np.int8)
    yaml_path = save_map(tmp_path / "map.yaml", grid, geometry, image_format)
    assert load_map(yaml_path) is not None
    with monkeypatch.context() as patch:
        patch.setattr(Image.Image, "save", cut_short(Image.Image.save))
        assert_stopped_write_keeps(tmp_path, lambda: save_map(tmp_path / "map.yaml", np.full((4, 6), 100, np.int8), geometry, image_format))
    before = yaml_path.read_bytes()
    cut_text_writes_short(monkeypatch)  # the image is written (whole) first, then the YAML
    with pytest.raises(KeyboardInterrupt):
        save_map(tmp_path / "map.yaml", np.full((4, 6), 100, np.int8), geometry, image_format)
    assert yaml_path.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["map." + image_format, "map.yaml"]
    assert (load_map(yaml_path)[0] == 100).all()  # the YAML kept, over the new image


def test_report_stopped_while_written_keeps_the_earlier_one(tmp_path, monkeypatch):
    """``report.html`` (eval's, up's, ``report``'s) was written in place."""
    from cso_runtime.evaluation import EvalRequest, run_eval
    from cso_runtime.report import write_report

    out = tmp_path / "o"
    run_eval(EvalRequest(methods=["greedy-dist"], maps="generated:small:1:0", out_dir=out, max_steps=5))
    assert (out / "report.html").is_file()
    summary = json.loads((out / "summary.json").read_text())
    cut_text_writes_short(monkeypatch)
    assert_stopped_write_keeps(out, lambda: write_report(out, summary))


def test_figures_stopped_while_written_keep_the_earlier_ones(tmp_path, monkeypatch):
    """The results folder's figures (coverage curves, trajectories: report.html shows them) were written in place."""
    from matplotlib.figure import Figure

    from cso_runtime import plots

    def figure() -> Any:
        fig, ax = plots.pyplot().subplots()
        ax.plot([0, 1], [0, 1])
        return fig

    plots._save(figure(), tmp_path / "coverage_curves.png", 50)
    monkeypatch.setattr(Figure, "savefig", cut_short(Figure.savefig))
    assert_stopped_write_keeps(tmp_path, lambda: plots._save(figure(), tmp_path / "coverage_curves.png", 50))


def test_paired_csv_stopped_while_written_keeps_the_earlier_one(tmp_path, monkeypatch):
    """``paired.csv`` (eval's, ``compare --csv``'s) was written in place: a stop between rows left a cut table."""
    from cso_runtime.comparison import CSV_FIELDS, write_csv

    rows = [dict.fromkeys(CSV_FIELDS, i) for i in range(3)]
    write_csv(tmp_path / "paired.csv", rows)
    real = csv.DictWriter.writerows

    def cut(self: csv.DictWriter, rowdicts: Any) -> None:
        real(self, list(rowdicts)[:1])
        raise KeyboardInterrupt

    monkeypatch.setattr(csv.DictWriter, "writerows", cut)
    assert_stopped_write_keeps(tmp_path, lambda: write_csv(tmp_path / "paired.csv", rows[::-1]))


def test_run_profile_stopped_while_written_keeps_the_earlier_one(tmp_path, monkeypatch):
    """A run folder's ``profile.yaml`` (every service reads it as it starts; written again when the folder is made
    again) was written in place."""
    from cso_runtime.launcher import Launcher
    from cso_runtime.run_profile import load_profile
    from tests.conftest import unset_weights_env

    unset_weights_env(monkeypatch)  # the sim profile's cso on the shipped weights, whatever the developer's environment gives
    profile, data = load_profile("sim")
    launcher = Launcher(profile, data, tmp_path)
    launcher.write_profile()
    assert launcher.profile_path.is_file()
    cut_text_writes_short(monkeypatch)
    assert_stopped_write_keeps(tmp_path, launcher.write_profile)


def test_an_eval_removes_the_partial_files_a_killed_one_left_anywhere_in_its_folder(tmp_path):
    """Every file of a results folder is now written beside itself first: those a ``kill -9`` left in ``maps/``,
    ``trajectories/`` and the folder itself (summary.json, the figures, report.html) go too, not only ``episodes/``'s."""
    from cso_runtime.outputs import episode_map_path, partial_path, remove_stale_partial_files, trajectory_plot_path

    stale = [partial_path(tmp_path / "summary.json"), partial_path(episode_map_path(tmp_path, "cso", "a")), partial_path(trajectory_plot_path(tmp_path, "a"))]
    for path in stale:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("half")
    (tmp_path / "summary.json").write_text("{}")
    (tmp_path / ".draft.partial").write_text("a hidden file of the user's, not one partial_path names")
    assert sorted(remove_stale_partial_files(tmp_path, [], lambda path: False)) == sorted(stale)
    assert sorted(p.name for p in tmp_path.rglob("*") if p.is_file()) == [".draft.partial", "summary.json"]


def test_a_partial_file_whose_pid_a_later_process_took_is_removed_and_a_live_writers_is_kept(tmp_path, monkeypatch):
    """A partial file's writer was judged alive whenever any process ran under the pid in its name: once an unrelated
    process took a dead writer's pid (the pids wrap round), its partial file was kept for good. A process that started
    after the file was last written is not its writer; one that started before may be (it is kept). Where the start
    time is unknown (no ``/proc``), a live pid is still taken for the writer."""
    import os
    import subprocess
    import sys
    import time

    from cso_runtime import supervision
    from cso_runtime.outputs import remove_partial_files

    later = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])  # started now: after `taken` was written
    try:
        taken = tmp_path / f".cso.pt.{later.pid}.partial"  # left an hour ago by a writer long gone, whose pid `later` took
        being_written = tmp_path / f".cso.json.{later.pid}.partial"  # written since `later` started: it may be its writer's
        for path in (taken, being_written):
            path.write_bytes(b"PK")
        an_hour_ago_s = time.time() - 3600
        os.utime(taken, (an_hour_ago_s, an_hour_ago_s))
        with monkeypatch.context() as m:
            m.setattr(supervision, "process_started_s", lambda pid: None)  # not Linux: no start time to tell them apart
            assert remove_partial_files([tmp_path]) == [] and taken.is_file()
        assert supervision.pid_alive(later.pid)
        assert remove_partial_files([tmp_path]) == [taken]
        assert being_written.is_file() and not taken.exists()
    finally:
        later.kill()
        later.wait()


def test_a_whole_write_keeps_the_files_mode_and_owner_and_writes_through_a_link(tmp_path):
    """A file written in place kept its permissions and owner, and a symlink stayed a link to the file written. The
    file written beside it and renamed over it had this process's umask and owner, and took the link's place: a map
    the user made private (0600) became world-readable, a summary linked from elsewhere stopped being updated there."""
    import os

    from cso_runtime.outputs import write_text_atomic

    private = tmp_path / "map.yaml"
    private.write_text("earlier\n")
    private.chmod(0o600)
    write_text_atomic(private, "new\n")
    assert private.read_text() == "new\n" and private.stat().st_mode & 0o777 == 0o600

    if os.geteuid() == 0:  # only root may give a file to another owner: the one case a replaced file could lose its owner
        owned = tmp_path / "summary.json"
        owned.write_text("{}")
        os.chown(owned, 4321, 4322)
        write_text_atomic(owned, "{}\n")
        assert (owned.stat().st_uid, owned.stat().st_gid) == (4321, 4322)

    shared = tmp_path / "elsewhere" / "report.html"
    shared.parent.mkdir()
    shared.write_text("earlier")
    link = tmp_path / "out" / "report.html"
    link.parent.mkdir()
    link.symlink_to(shared)
    write_text_atomic(link, "new")
    assert link.is_symlink() and shared.read_text() == "new"
    assert not [p for p in (*link.parent.iterdir(), *shared.parent.iterdir()) if p.name.endswith(".partial")]


def test_a_live_writer_is_not_taken_for_a_stranger_where_proc_uptime_is_the_containers_age(tmp_path, monkeypatch):
    """``process_started_s`` placed a process's start (``/proc/<pid>/stat``, ticks since the host's boot) by
    ``/proc/uptime``, which LXCFS (LXD, Incus, some Docker hosts) makes the container's age: every start fell in the
    future, so a live writer's partial file was judged left by a dead one (its pid taken since) and removed as it was
    being written. The start is now placed on the clock it is counted on (``CLOCK_BOOTTIME``)."""
    import builtins
    import io
    import subprocess
    import sys
    import time

    from cso_runtime import supervision
    from cso_runtime.outputs import remove_partial_files

    real_open = builtins.open

    def lxcfs_open(file: Any, *args: Any, **kwargs: Any) -> Any:
        if str(file) == "/proc/uptime":  # a container started 5 s ago on a host up far longer
            return io.StringIO("5.00 9.00\n")
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(supervision, "open", lxcfs_open, raising=False)
    before_s = time.time()
    writer = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    after_s = time.time()
    try:
        being_written = tmp_path / f".cso.pt.{writer.pid}.partial"
        being_written.write_bytes(b"PK")
        started_s = supervision.process_started_s(writer.pid)
        assert started_s is not None and before_s - 1.0 <= started_s <= after_s + 1.0
        assert remove_partial_files([tmp_path]) == [] and being_written.is_file()
    finally:
        writer.kill()
        writer.wait()


def test_a_text_file_naming_a_path_of_bytes_that_are_no_utf8_is_written_with_it_escaped(tmp_path):
    """A run's report names its scene's path, which may hold bytes that are no UTF-8 (a lone surrogate as Python reads
    it, ``os.fsdecode``): the write raised, and ``up`` ended with no report.html, ``eval`` with a traceback and no
    episodes.csv. The surrogate is written escaped (``\\udcff``), as ``config.utf8_text`` writes a scene's name."""
    import os

    from cso_runtime.outputs import write_text_atomic

    report = tmp_path / "report.html"
    write_text_atomic(report, "scene " + os.fsdecode(b"/maps/img_\xff.png") + " é")
    assert report.read_text(encoding="utf-8") == "scene /maps/img_\\udcff.png é"
    assert [p.name for p in tmp_path.iterdir()] == ["report.html"]
