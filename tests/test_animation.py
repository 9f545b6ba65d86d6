"""``cso-runtime animate``: a recorded run as an animated GIF (the in-process ``eval --animate`` is in test_eval.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from cso_runtime import frames
from cso_runtime.animation import animate_recording
from cso_runtime.cli import app
from cso_runtime.geometry import Pose2D
from cso_runtime.keys import RobotKeys
from cso_runtime.messages import OdometryMsg, encode
from cso_runtime.recording import RecordedMessage, RecordingError, write_recording
from tests.test_bag_export import GEOM, T0_NS, _frontiers, episode, legacy


def test_a_recording_becomes_a_frame_after_each_decision_and_the_final_map(tmp_path):
    """Decisions at steps 0, 2 and 4 (the recorded goals): a frame at the next map, with the odometry's pose and
    path; the final map adds no frame when nothing moved since; a payload that does not decode is counted."""
    keys = RobotKeys("r0")
    messages = episode(keys, 6, T0_NS, 1_000_000)
    messages.insert(10, RecordedMessage(keys.topic("map"), T0_NS + 5, b"\x93garbage"))
    f_t = _frontiers(0)
    f_t.arrays["frontier"][4, 6:9] = True  # a frontier of three cells at (-0.35..-0.15, -0.05) m
    messages = [RecordedMessage(m.key, m.log_time_ns, encode(f_t)) if m.key.endswith("/frontiers") and m.log_time_ns < T0_NS + 1_000_000 else m for m in messages]
    write_recording(tmp_path / "run.mcap", "r0", messages)
    stats = animate_recording(tmp_path / "run.mcap", tmp_path / "run.gif")
    assert (stats.robot, stats.decisions, stats.maps, stats.rejected, stats.frames) == ("r0", 3, 6, 1, 3)
    scale = frames.frame_scale(GEOM.shape)
    with Image.open(tmp_path / "run.gif") as im:
        assert im.n_frames == 3 and im.size == (GEOM.shape[1] * scale, GEOM.shape[0] * scale)
        im.seek(2)
        last = np.asarray(im.convert("RGB"))
    x, y = 0.1 * 5, 0.0  # the odometry of step 5, the last map's
    row = last.shape[0] - 1 - int((y - GEOM.origin_y_m) / GEOM.resolution_m * scale)
    assert tuple(last[row, int((x - GEOM.origin_x_m) / GEOM.resolution_m * scale)]) in (frames.ROBOT, frames.HEADING)
    assert (last == frames.PATH).all(axis=2).any() and (last == frames.FREE).all(axis=2).any()
    with Image.open(tmp_path / "run.gif") as im:
        first = np.asarray(im.convert("RGB"))  # after the decision of step 0: its frontier cells
    assert (first == frames.FRONTIER).all(axis=2).sum() == 3 * scale * scale and not (last == frames.FRONTIER).all(axis=2).any()

    r = CliRunner().invoke(app, ["animate", str(tmp_path / "run.mcap"), "--max-frames", "2"])
    assert r.exit_code == 0 and "run.gif (robot r0): 2 frames from 3 decisions and 6 maps" in r.output, r.output
    assert "left out, did not decode: 1 payloads" in r.output


def test_animate_refuses_what_it_cannot_draw(tmp_path):
    both = episode(RobotKeys("r0"), 2, T0_NS, 1000) + episode(RobotKeys("r1"), 2, T0_NS, 1000)
    write_recording(tmp_path / "two.mcap", "*", sorted(both, key=lambda m: m.log_time_ns))
    with pytest.raises(RecordingError, match="robots r0, r1: give --robot ID"):
        animate_recording(tmp_path / "two.mcap", tmp_path / "x.gif")
    with pytest.raises(RecordingError, match="no messages of robot 'r7'"):
        animate_recording(tmp_path / "two.mcap", tmp_path / "x.gif", robot="r7")
    assert animate_recording(tmp_path / "two.mcap", tmp_path / "r1.gif", robot="r1").frames >= 1
    odometry_only = [RecordedMessage(RobotKeys("r0").topic("odom"), T0_NS, encode(OdometryMsg(0, 0.0, Pose2D(0.0, 0.0, 0.0))))]
    write_recording(tmp_path / "odom.mcap", "r0", odometry_only)
    with pytest.raises(RecordingError, match="no map and odometry of robot r0: nothing to animate"):
        animate_recording(tmp_path / "odom.mcap", tmp_path / "x.gif")
    assert not (tmp_path / "x.gif").exists()
    r = CliRunner().invoke(app, ["animate", str(tmp_path / "missing.mcap")])
    assert r.exit_code == 2 and "error: no such recording" in r.output
    r = CliRunner().invoke(app, ["animate", str(tmp_path / "two.mcap"), "--out", str(tmp_path / "two.mcap")])
    assert r.exit_code == 2 and "is the recording itself" in r.output
    for out in (tmp_path / "frames.txt", tmp_path / "noext", tmp_path):  # not an image file PIL can animate
        r = CliRunner().invoke(app, ["animate", str(tmp_path / "two.mcap"), "--out", str(out)])
        assert r.exit_code == 2 and "must be a file ending in .gif" in r.output, r.output



def test_a_recording_of_the_versions_before_the_episode_id_animates_as_today(tmp_path):
    """Odometry, goals and frontiers of the versions before the episode id: read, not left out."""
    keys = RobotKeys("r0")
    today = episode(keys, 6, T0_NS, 1_000_000)
    old = [RecordedMessage(m.key, m.log_time_ns, legacy(m.payload)) for m in today]
    assert sum(o.payload != m.payload for o, m in zip(old, today)) > 0  # some messages are of the older versions
    write_recording(tmp_path / "old.mcap", "r0", old)
    write_recording(tmp_path / "today.mcap", "r0", today)
    stats = animate_recording(tmp_path / "old.mcap", tmp_path / "old.gif")
    assert (stats.decisions, stats.maps, stats.rejected, stats.frames) == (3, 6, 0, 3)
    assert dataclasses.replace(animate_recording(tmp_path / "today.mcap", tmp_path / "today.gif"), path=stats.path) == stats

    def frames_of(gif):
        pictures = []
        with Image.open(gif) as im:
            for k in range(im.n_frames):
                im.seek(k)
                pictures.append(np.asarray(im.convert("RGB")))
        return pictures

    old_frames, today_frames = frames_of(tmp_path / "old.gif"), frames_of(tmp_path / "today.gif")
    assert len(old_frames) == len(today_frames) == 3
    for k, (a, b) in enumerate(zip(old_frames, today_frames)):
        np.testing.assert_array_equal(a, b, err_msg=f"frame {k}")  # the same picture: robot, path, goal and frontiers


def test_a_gif_that_fails_halfway_leaves_the_earlier_one_whole_and_nothing_cut(tmp_path, monkeypatch):
    """A disk that fills, or a kill, while the GIF is written: the file at the path is the earlier one, never a cut GIF
    (``up --animate``'s report links it), and no partial file is left beside it."""
    write_recording(tmp_path / "run.mcap", "r0", episode(RobotKeys("r0"), 4, T0_NS, 1_000_000))
    animate_recording(tmp_path / "run.mcap", tmp_path / "run.gif")
    earlier = (tmp_path / "run.gif").read_bytes()
    save = Image.Image.save

    def disk_full(self, fp, *args, **kwargs):
        save(self, fp, *args, **kwargs)
        with open(fp, "r+b") as fh:  # what a full disk leaves: the first bytes
            fh.truncate(100)
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Image.Image, "save", disk_full)
    with pytest.raises(OSError, match="No space left"):
        animate_recording(tmp_path / "run.mcap", tmp_path / "run.gif", max_frames=2)
    assert (tmp_path / "run.gif").read_bytes() == earlier
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.gif", "run.mcap"]
    monkeypatch.setattr(Image.Image, "save", save)
    animate_recording(tmp_path / "run.mcap", tmp_path / "run.png", max_frames=2)  # an animated PNG, by its name
    with Image.open(tmp_path / "run.png") as im:
        assert im.format == "PNG" and im.n_frames == 2


@pytest.mark.parametrize("status_after_goal", [False, True], ids=["status-first", "goal-first"])
def test_a_goal_decided_on_the_map_the_episode_ended_at_is_no_decision(tmp_path, status_after_goal):
    """The frontier service decides on the map of the step at which the sim ends the episode (it hears of the end
    later): that goal is published and recorded, but no robot acts on it, and neither the sim's count (``up``'s
    summary) nor the in-process episode's (``eval``: no decision after its last step) has it. ``animate`` counted
    it: 25 decisions against ``up``'s 24. A goal of the step the episode ended at, heard before or after the end's
    status, is not counted; an empty goal there (the ``no_frontier`` end itself) is, as by the sim and eval."""
    from cso_runtime.messages import EpisodeStatusMsg, GoalMsg

    keys = RobotKeys("r0")
    messages = episode(keys, 5, T0_NS, 1_000_000)  # goals decided at steps 0, 2 and 4
    end_ns = T0_NS + 4 * 1_000_000 + (5500 if status_after_goal else 3500)  # the map of step 4 at +3000, its goal at +5000
    ended = EpisodeStatusMsg(state="done", step=4, decisions=2, terminated_by="coverage")
    write_recording(tmp_path / "run.mcap", "r0", sorted([*messages, RecordedMessage(keys.topic("episode_status"), end_ns, encode(ended))], key=lambda m: m.log_time_ns))
    assert animate_recording(tmp_path / "run.mcap", tmp_path / "run.gif").decisions == 2 == ended.decisions
    # The no_frontier end: the empty goal of step 4 is the episode's last decision.
    empty = [RecordedMessage(m.key, m.log_time_ns, encode(GoalMsg(4, True, None, None, method="greedy-dist"))) if m.key.endswith("/goal") and m.log_time_ns >= T0_NS + 4 * 1_000_000 else m for m in messages]
    no_frontier = EpisodeStatusMsg(state="done", step=4, decisions=3, terminated_by="no_frontier")
    write_recording(tmp_path / "nf.mcap", "r0", sorted([*empty, RecordedMessage(keys.topic("episode_status"), end_ns, encode(no_frontier))], key=lambda m: m.log_time_ns))
    assert animate_recording(tmp_path / "nf.mcap", tmp_path / "nf.gif").decisions == 3
