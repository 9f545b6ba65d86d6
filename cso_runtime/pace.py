"""How fast simulated time runs against the wall clock: the real-time factor that MuJoCo users read off a run
(``episodes.csv``'s ``real_time_factor``, ``up``'s live view and progress lines)."""

from __future__ import annotations

import math


def real_time_factor(sim_s: float | None, wall_s: float | None) -> float | None:
    """Simulated seconds per wall-clock second (2.0: twice as fast as real time); None when either is unknown
    (a real robot has no simulated time) or either clock did not move: an episode of no step ran no simulated time,
    which gives no pace to speak of (0.0 would read as infinitely slow)."""
    if sim_s is None or wall_s is None or not (math.isfinite(sim_s) and math.isfinite(wall_s) and sim_s > 0 and wall_s > 0):
        return None
    return sim_s / wall_s


def real_time_words(real_time_factor: float) -> str:
    """``1.00x real time``: how ``up``'s live view and progress lines and ``status`` word the factor."""
    return f"{real_time_factor:.2f}x real time"


class StepPace:
    """The real-time factor of a running episode, measured on its statuses as they arrive: the steps from the first
    status past its start to the latest, times the control period, over the wall-clock time between their arrivals.
    Start-up (services coming up, the sim waiting for them) is left out, which ``up``'s ``wall_s`` includes; a new
    episode (a restarted sim) starts the measure over."""

    def __init__(self, control_period_s: float) -> None:
        self.control_period_s = control_period_s
        self._measure: tuple[tuple[int, int, float], tuple[int, float] | None] | None = None
        """(episode, step, arrival time in s) of the first status counted, and (step, arrival time in s) of the latest
        beyond it (None before one). One attribute, replaced whole: ``observe`` runs on a Zenoh thread while the run
        loop and the status queryable read ``real_time_factor``, with no lock, and a reader between two writes of two
        attributes (a new episode's first, then its latest set to None) unpacked a None."""

    def observe(self, episode: int, step: int, at_s: float) -> None:
        """A status of ``episode`` at ``step`` (past its start) arrived at ``at_s`` (a monotonic clock, s)."""
        measure = self._measure
        if measure is None or episode != measure[0][0]:
            self._measure = ((episode, step, at_s), None)
            return
        first, latest = measure
        if step > first[1] and (latest is None or step >= latest[0]):
            self._measure = (first, (step, at_s))

    @property
    def real_time_factor(self) -> float | None:
        """None until two statuses of one episode, some steps apart, have arrived."""
        measure = self._measure  # read once: ``observe`` may replace it meanwhile
        if measure is None:
            return None
        (_, first_step, first_s), latest = measure
        if latest is None:
            return None
        step, at_s = latest
        return real_time_factor((step - first_step) * self.control_period_s, at_s - first_s)
