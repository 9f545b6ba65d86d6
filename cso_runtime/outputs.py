"""Where ``eval`` and ``up`` put each file of a results folder: one layout, read by the report too.

    summary.json, episodes.csv, paired.csv, report.html, the figures below
    episodes/<method>/<map>.npz         arrays and metric row of one episode (<method> as ``file_stem`` writes it:
                                        a method of one's own ``pkg.mod:Sel`` in ``episodes/pkg.mod_Sel/``)
    maps/<method>/<map>.yaml, .png      the robot's final map (Nav2 map_server files)
    animations/<method>/<map>.gif       with --animate
    trajectories/<map>.png              every method's path on one plan
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
import stat
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

COVERAGE_FIGURE = "coverage_curves.png"
EFFICIENCY_FIGURE = "efficiency_by_scale.png"
PAIRED_FIGURE = "paired_efficiency.png"
REPORT_NAME = "report.html"
"""eval's and ``up``'s page of results (``report.write_report``)."""


def file_stem(scene: str) -> str:
    """A scene or method name as one file or folder name (a real robot's scene is ``ros2:<namespace>``, a method of
    the user's own ``module.path:Attribute``): each character but letters, digits, ``.``, ``_`` and ``-`` becomes ``_``."""
    return re.sub(r"[^A-Za-z0-9._-]", "_", scene) or "scene"


def episode_npz_path(out_dir: Path, method: str, scene: str) -> Path:
    """Where an episode's arrays and metric row go (``evaluation.save_episode_files``)."""
    return Path(out_dir) / "episodes" / file_stem(method) / f"{file_stem(scene)}.npz"


def episode_map_path(out_dir: Path, method: str, scene: str) -> Path:
    """Where an episode's final map goes: a Nav2 map_server YAML, its PNG beside it."""
    return Path(out_dir) / "maps" / file_stem(method) / f"{file_stem(scene)}.yaml"


def episode_animation_path(out_dir: Path, method: str, scene: str) -> Path:
    """Where ``eval --animate`` writes one episode's GIF."""
    return Path(out_dir) / "animations" / file_stem(method) / f"{file_stem(scene)}.gif"


def trajectory_plot_path(out_dir: Path, scene: str) -> Path:
    """Every method's path on one plan."""
    return Path(out_dir) / "trajectories" / f"{file_stem(scene)}.png"


RESULTS_FILES = "report.html (all of it, for a browser), summary.json, episodes.csv, the figures"
"""How ``results_said`` ends: the files, the one to open first first."""

NO_RESULTS = "no results: "
"""How the closing line of an ``up`` whose episode wrote no results begins (``Launcher.closing_line``)."""


def results_said(out_dir: Path) -> str:
    """The closing line of ``eval`` and of a finished ``up``: where the results are, and the file to open first."""
    return f"results in {out_dir}/: {RESULTS_FILES}"


def closes_a_run(log_line: str) -> bool:
    """Whether ``log_line`` (a line of a run's ``launcher.log``, as logged) is the launcher's closing line, its last:
    where the results went (``results_said``), or that there are none and what was kept (``NO_RESULTS``)."""
    line = log_line.rstrip()
    return line.endswith(f"/: {RESULTS_FILES}") or f": {NO_RESULTS}" in line


def file_sha256(path: Path) -> str:
    """The sha256 of the file at ``path``; "" when there is none (or it cannot be read)."""
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return ""


def write_whole(path: Path | str, write: Callable[[Path], object]) -> None:
    """Write ``path`` whole or not at all: ``write(partial)`` writes a file of its own beside it (``partial_path``),
    then it is renamed over ``path``, so that a crash, a kill, a full disk or a reader at the wrong moment sees the
    earlier file or the new one, never half of one, and a failed write leaves no partial file. The one way every
    file another command or a resume reads is written (summaries, tables, episodes, maps, figures, weights).

    As a write in place would: a symlink is written through (the file it names is replaced, beside itself), and an
    earlier file's permissions and owner are kept (``keep_mode_and_owner``)."""
    path = Path(path)
    if path.is_symlink():
        path = Path(os.path.realpath(path))
    partial = partial_path(path)
    try:
        write(partial)
        keep_mode_and_owner(path, partial)
        os.replace(partial, path)
    finally:
        partial.unlink(missing_ok=True)


def keep_mode_and_owner(earlier: Path, partial: Path) -> None:
    """Give ``partial`` the permissions and owner of ``earlier``, the file it replaces (none: nothing to keep): a
    private file (0600) stays private, a read-only one read-only. The owner only where this process may give it
    (root, or a group of its own); otherwise the file is this process's, as a new one would be."""
    try:
        st = os.stat(earlier)
    except FileNotFoundError:
        return
    if (st.st_uid, st.st_gid) != (os.geteuid(), os.getegid()):
        with contextlib.suppress(OSError):
            os.chown(partial, st.st_uid, st.st_gid)
    os.chmod(partial, stat.S_IMODE(st.st_mode))


def write_text_atomic(path: Path | str, text: str) -> None:
    """``text`` (UTF-8) as the whole of ``path`` (``write_whole``). A character UTF-8 cannot carry (a lone surrogate: a
    path of bytes that are no UTF-8, ``os.fsdecode``'s) is written escaped, ``\\udcff``, as ``config.utf8_text`` does,
    where it raised and left a run without its report."""
    write_whole(path, lambda partial: partial.write_text(text, encoding="utf-8", errors="backslashreplace"))


def write_npz_whole(path: Path | str, arrays: Mapping[str, Any]) -> None:
    """``arrays`` as a compressed npz at exactly ``path`` (numpy would add ``.npz`` to a name without it), whole."""
    import numpy as np  # noqa: PLC0415  (the results layout alone needs none)

    def write(partial: Path) -> None:
        with partial.open("wb") as fh:  # a file, not its name: numpy would add .npz to the partial file's
            np.savez_compressed(fh, **arrays)

    write_whole(path, write)


def partial_path(path: Path) -> Path:
    """Where ``path`` is written before it is renamed over it (whole or not at all): hidden, this process's own, and
    ending in ``.partial``, so that no reader of the results folder takes one a kill left (``<map>.partial.npz``
    was an episode file to a glob, and the name of a plan ``<map>.partial``'s own)."""
    return path.with_name(f".{path.name}.{os.getpid()}.partial")


PARTIAL_NAME = re.compile(r"\.(?P<name>.+)\.(?P<pid>\d+)\.partial")
"""The names ``partial_path`` gives (``.<name>.<pid>.partial``): the files a clean-up removes, and no other hidden file."""


RESULT_FILE_FOLDERS = ("episodes", "animations", "maps")
"""The folders of ``--out`` with a folder per method; every file of ``--out`` is written beside itself first
(``partial_path``, ``write_whole``)."""

EVAL_RESULT_FILES = ("summary.json", "episodes.csv", "paired.csv", REPORT_NAME, COVERAGE_FIGURE, EFFICIENCY_FIGURE, PAIRED_FIGURE)
"""The files eval writes at the top of ``--out``."""

EVAL_FILE_SUFFIXES = {"episodes": (".npz",), "animations": (".gif",), "maps": (".yaml", ".png"), "trajectories": (".png",)}
"""What eval writes in each folder of ``--out``: a method's episodes, animations and maps, the plans' trajectories."""


def is_an_eval_file(out_dir: Path, path: Path) -> bool:
    """Whether ``path`` is where eval writes one of its files in ``out_dir`` (``EVAL_RESULT_FILES``, ``EVAL_FILE_SUFFIXES``):
    the partial files of anything else there (a ``train`` into the same folder, a tool of one's own) are not eval's to remove."""
    try:
        parts = Path(path).relative_to(out_dir).parts
    except ValueError:
        return False
    if len(parts) == 1:
        return parts[0] in EVAL_RESULT_FILES
    in_its_folder = len(parts) == (3 if parts[0] in RESULT_FILE_FOLDERS else 2)  # episodes/<method>/<map>.npz, trajectories/<map>.png
    return in_its_folder and Path(parts[-1]).suffix in EVAL_FILE_SUFFIXES.get(parts[0], ())


def remove_stale_partial_files(out_dir: Path, episode_files: list[Path], is_an_episode: Callable[[Path], bool]) -> list[Path]:
    """Remove the partial files a killed eval left in ``out_dir`` (``kill -9`` while it wrote an episode file, a GIF, a map, a figure or a summary),
    and the ``<map>.partial.npz`` an earlier version left beside each of ``episode_files`` (the episodes this eval runs;
    one that is itself one of them, or ``is_an_episode``, the finished episode of a plan named ``<map>.partial`` that
    this eval leaves out, is kept); the ones removed. Only while holding the folder's eval lock, and only the partial
    files of eval's own files (``is_an_eval_file``) whose writer is gone (``remove_partial_files``)."""
    episodes = set(episode_files)
    folders = [method for folder in RESULT_FILE_FOLDERS for method in sorted((Path(out_dir) / folder).glob("*")) if method.is_dir()]
    folders += [Path(out_dir), Path(out_dir) / "trajectories"]  # summary.json, report.html, the figures
    legacy = [path.with_name(f"{path.stem}.partial.npz") for path in episode_files]
    also = [path for path in legacy if path not in episodes and path.is_file() and not is_an_episode(path)]
    return remove_partial_files(folders, also=also, written_for=lambda path: is_an_eval_file(out_dir, path))


def partial_file_writer(path: Path) -> tuple[Path, int] | None:
    """The file a partial file (``partial_path``) was written for and the process that wrote it; None for another name."""
    found = PARTIAL_NAME.fullmatch(path.name)
    return (path.with_name(found["name"]), int(found["pid"])) if found else None


WRITER_START_SLACK_S = 2.0
"""How much later than a partial file's last write (its mtime) the process under its pid must have started to be
judged another process, one that took the dead writer's pid (``writer_gone``): the start time is known to a clock tick
and the time since boot, an mtime to its file system's resolution (2 s on FAT)."""


def writer_gone(pid: int, written_s: float | None = None) -> bool:
    """Whether the process that named a partial file ``pid`` writes it no more: no process runs under that pid (a live
    one is writing it: another command into the same folder, under another lock or none), or the one that runs under it
    started after the file was last written (``written_s``, its mtime; more than ``WRITER_START_SLACK_S`` after), so is
    not its writer but a process that took the dead writer's pid (Linux ``/proc``; elsewhere a live pid is taken for
    the writer), or it is this very process, which holds the folder's lock and has written nothing into it yet when it
    cleans up (a file of its pid is one an earlier process of that pid left)."""
    from cso_runtime.supervision import pid_alive, process_started_s  # noqa: PLC0415 - its process helpers only for a clean-up

    if pid == os.getpid() or not pid_alive(pid):
        return True
    if written_s is None:
        return False
    started_s = process_started_s(pid)
    return started_s is not None and started_s > written_s + WRITER_START_SLACK_S


def remove_partial_files(folders: Iterable[Path], also: Iterable[Path] = (), written_for: Callable[[Path], bool] | None = None) -> list[Path]:
    """Remove the partial files (``partial_path``) a killed writer left directly in each of ``folders``, then the
    files ``also``; the ones removed. Only while holding the lock of the command that writes those folders
    (``current_run.folder_lock``), and only a partial file whose writer has gone (``writer_gone``) and, with
    ``written_for``, that was written for a file it accepts (the caller's own kind): never a user's other hidden file
    nor the partial files of another command's kind of file in the same folder."""
    removed = []
    partial = []
    for path in (path for folder in folders for path in sorted(Path(folder).glob(".*.partial"))):
        writer = partial_file_writer(path)
        if writer is None or (written_for is not None and not written_for(writer[0])):
            continue
        try:
            written_s = path.stat().st_mtime
        except OSError:  # gone meanwhile (its writer renamed it into place)
            continue
        if writer_gone(writer[1], written_s):
            partial.append(path)
    for path in partial + list(also):
        if path.is_file():
            path.unlink(missing_ok=True)
            removed.append(path)
    return removed
