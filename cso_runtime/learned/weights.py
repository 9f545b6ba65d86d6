"""Where the learned methods' weights live, without importing torch (the launcher and the CLI check
them before anything starts; ``registry`` loads them).

The shipped files are ``cso_runtime/data/weights/<method>.pt``; ``$CSO_WEIGHTS_DIR`` (or ``--weights FOLDER``
on ``eval`` and ``up``) points every process of a run at a training run's folder instead.

A policy is trained for one sensor. Where the folder also holds ``<method>@fov<deg>.pt`` (weights trained
with a sensor of that field of view, e.g. ``cso@fov180.pt`` for the LIMO's 180-degree LiDAR), an episode with
that field of view uses it; every other sensor uses ``<method>.pt``.

``$CSO_WEIGHTS_FILE`` (or ``--weights FILE``) names one file instead: its method (the one it is named for) uses
exactly that file, whatever the sensor; nothing beside it takes its place.
"""

from __future__ import annotations

import collections
import dataclasses
import io
import json
import os
import pickle
import zipfile
from collections.abc import Mapping
from importlib import resources
from pathlib import Path
from typing import Any

from cso_runtime.config import LIDAR_FOVS_DEG, ConfigError, FrontierConfig, MaskConfig, SensorConfig, finite_number, setting_text
from cso_runtime.outputs import file_sha256

WEIGHTS_DIR_ENV = "CSO_WEIGHTS_DIR"
"""Environment variable naming a folder of ``<method>.pt`` files to use instead of the shipped ones
(evaluate your own training runs with ``eval`` or the policy service; child processes inherit it)."""


WEIGHTS_FILE_ENV = "CSO_WEIGHTS_FILE"
"""Environment variable naming one ``<method>.pt`` (or ``<method>@fov<deg>.pt``) file that its method uses exactly,
whatever the sensor (``--weights FILE``; child processes inherit it). The other methods use ``weights_dir``'s."""


def given_weights_file() -> Path | None:
    """The file of ``$CSO_WEIGHTS_FILE`` (``--weights FILE``), None when none is given."""
    given = os.environ.get(WEIGHTS_FILE_ENV)
    return Path(given) if given else None


def method_of_file(path: Path) -> str:
    """The method a weights file is named for: ``cso`` for ``cso.pt`` and ``cso@fov180.pt``."""
    return path.stem.split("@fov")[0]


def weights_dir() -> Path:
    """The folder of weights files: ``$CSO_WEIGHTS_DIR`` when set (``--weights FOLDER``, a training run's), else the shipped ones."""
    override = os.environ.get(WEIGHTS_DIR_ENV)
    if override:
        return Path(override)
    return Path(str(resources.files("cso_runtime") / "data" / "weights"))


def sensor_tag(sensor: SensorConfig) -> str:
    """The file-name tag of weights trained with ``sensor``: its field of view (``fov180``)."""
    return f"fov{sensor.fov_deg:g}"


def weights_path(name: str, sensor: SensorConfig | None = None) -> Path:
    """``name``'s weights file: the file given for it (``$CSO_WEIGHTS_FILE``, ``--weights FILE``) whatever the sensor;
    else ``<name>@<sensor_tag>.pt`` when ``sensor`` is given and the folder has one trained with its field of view,
    else ``<name>.pt``."""
    given = given_weights_file()
    if given is not None and method_of_file(given) == name:
        return given
    folder = weights_dir()
    if sensor is not None:
        matched = folder / f"{name}@{sensor_tag(sensor)}.pt"
        if matched.is_file():
            return matched
    return folder / f"{name}.pt"


def has_weights(name: str, sensor: SensorConfig | None = None) -> bool:
    """True when ``name``'s weights file is where ``weights_path`` says (shipped, or in ``$CSO_WEIGHTS_DIR``)."""
    return weights_path(name, sensor).is_file()


def weights_file_problem(name: str, sensor: SensorConfig | None = None) -> str:
    """Why ``name``'s weights file cannot be a torch checkpoint, judged from its first bytes without
    torch (the launcher checks before anything starts); empty when it may be one. ``registry.load_checkpoint``
    says more about a file that passes this but still does not load."""
    path = weights_path(name, sensor)
    try:
        with path.open("rb") as fh:
            head = fh.read(4)
    except OSError as exc:
        return f"{path}: cannot read it ({exc.strerror or exc})"
    if not head:
        return f"{path}: empty file"
    if head.startswith((b"PK\x03\x04", b"\x80")):  # torch.save's zip archive, or its legacy pickle
        return ""
    return f"{path}: not a torch checkpoint (neither a zip archive nor a pickle)"


RESUMABLE_CHECKPOINT = "checkpoint.pt"
"""What ``train`` saves every few updates to ``--resume`` from: weights with the optimiser's and the RNGs' states,
not a method's weights file."""


def named_for_a_method(path: Path) -> bool:
    """True for ``<method>.pt`` or ``<method>@fov<deg>.pt`` of a learned method: the files ``weights_path`` finds."""
    from cso_runtime.policies import LEARNED_METHODS  # noqa: PLC0415 - no torch; policies imports this module

    return path.suffix == ".pt" and method_of_file(path) in LEARNED_METHODS


def use_weights(given: str | Path) -> Path:
    """Serve the learned methods from ``given`` in this process and the ones it starts (``eval --weights``,
    ``up --weights``): a ``train --out`` folder of ``<method>.pt`` (each method its file, or its ``@fov<deg>`` one for
    a sensor of that field of view), or one such file, which its method then uses exactly, whatever the sensor. Returns
    the folder or file. Raises ValueError, saying what to give instead, for anything else: a file not named for its
    method, the checkpoint, a folder of no method's file (an unfinished run's: how to finish it)."""
    from cso_runtime.policies import LEARNED_METHODS  # noqa: PLC0415 - no torch; policies imports this module

    path = Path(given).expanduser().resolve()
    # A file's method is read from the name given (a link best/cso.pt to a run's step_100.pt is cso's), not its target's.
    named = Path(given).expanduser().absolute().parent.resolve() / Path(given).expanduser().name
    if not path.exists():  # said as the path given, not as a folder of no weights or as the shipped ones
        link = f" (a link to {path}, which is not there)" if named.is_symlink() else ""
        raise ValueError(f"--weights {given}: no such file or folder{link}")
    if named.is_file() and named.name != RESUMABLE_CHECKPOINT and named.suffix == ".pt":
        path = named
        if not named_for_a_method(path):  # which method it is for is read from its name
            raise ValueError(
                f"--weights {given}: a learned method's weights are found by their file name, and this one is not named for its method"
                f" ({', '.join(f'{m}.pt' for m in LEARNED_METHODS)}); copy it as the method it was trained as"
                f" (cso.pt for train --variant cso) and give that file"
            )
        os.environ.pop(WEIGHTS_DIR_ENV, None)  # the other methods: the shipped ones (weights_file_refusal keeps them out)
        os.environ[WEIGHTS_FILE_ENV] = str(path)
        return path
    run = path.parent if path.is_file() and path.name == RESUMABLE_CHECKPOINT else path
    if not run.is_dir():
        raise ValueError(f"--weights {given}: not a folder (give a training run's --out, which holds <method>.pt)")
    served = sorted(p.name for p in run.glob("*.pt") if named_for_a_method(p))
    if served and run != path:
        raise ValueError(f"--weights {given}: a training checkpoint (what train --resume goes on from), not a method's weights; give its folder {run}, which holds {', '.join(served)}")
    if not served and (run / RESUMABLE_CHECKPOINT).is_file():
        raise ValueError(
            f"--weights {given}: only a training checkpoint ({RESUMABLE_CHECKPOINT}: a run that has not finished), no <method>.pt; "
            f"finish it with `cso-runtime train --resume {run / RESUMABLE_CHECKPOINT}` (it holds the run's configuration),"
            " or add --total-decisions 1 to write its weights as they are and evaluate them now"
        )
    if not served:
        others = sorted(p.name for p in run.glob("*.pt"))
        held = f"; it holds {', '.join(others)}: copy the one to use as its method's name" if others else ""
        folders = sorted(d.name for d in run.iterdir() if d.is_dir() and any(named_for_a_method(p) for p in d.glob("*.pt")))
        if folders and not others:  # a run's checkpoints/ (train's keep_checkpoints): each of its folders is one policy
            shown = ", ".join(folders) if len(folders) <= 3 else f"{folders[0]}, ..., {folders[-1]}"
            held = f"; its folders {shown} hold such files: give one of them"
        raise ValueError(f"--weights {given}: no file named for a learned method's weights in it ({', '.join(f'{m}.pt' for m in LEARNED_METHODS)}){held}")
    os.environ.pop(WEIGHTS_FILE_ENV, None)
    os.environ[WEIGHTS_DIR_ENV] = str(path)
    return path


def given_weights_problem() -> str:
    """Why the weights the environment names cannot be used, naming the path exactly as given: a ``$CSO_WEIGHTS_FILE``
    that is no file or not named for a learned method, a ``$CSO_WEIGHTS_DIR`` that is no folder; empty when neither is
    set or both may be used. Said before anything starts: otherwise a method would be said to have no weights in
    another folder (the shipped one), or run the shipped weights unasked. ``--weights`` (``use_weights``) checks what it
    is given itself, and sets these only to a file or folder that is there."""
    from cso_runtime.policies import LEARNED_METHODS  # noqa: PLC0415 - no torch; policies imports this module

    given = os.environ.get(WEIGHTS_FILE_ENV)
    if given:
        if Path(given).is_dir():
            return f"{WEIGHTS_FILE_ENV}={given}: a folder, not a file (give a folder of <method>.pt as {WEIGHTS_DIR_ENV}, or --weights FOLDER)"
        if not Path(given).is_file():
            return f"{WEIGHTS_FILE_ENV}={given}: no such file (unset it to run the shipped weights)"
        if not named_for_a_method(Path(given)):
            return f"{WEIGHTS_FILE_ENV}={given}: not named for a learned method's weights ({', '.join(f'{m}.pt' for m in LEARNED_METHODS)})"
    folder = os.environ.get(WEIGHTS_DIR_ENV)
    if folder and not Path(folder).is_dir():
        return f"{WEIGHTS_DIR_ENV}={folder}: no such folder (unset it to run the shipped weights)"
    return ""


def weights_file_refusal(names: list[str]) -> str:
    """Why ``names`` (a run's methods) cannot run with the weights the environment gives: a file or folder that is not
    there (``given_weights_problem``), or the file given (``--weights FILE``) holds one method's weights, and another
    learned method would run with the shipped ones, unasked; empty when ``names`` has no learned method, or no file is
    given and the folder is there, or every learned method of ``names`` is the file's method."""
    from cso_runtime.policies import LEARNED_METHODS  # noqa: PLC0415 - no torch; policies imports this module

    if not any(n in LEARNED_METHODS for n in names):
        return ""
    if problem := given_weights_problem():
        return problem
    given = given_weights_file()
    if given is None:
        return ""
    others = [n for n in names if n in LEARNED_METHODS and n != method_of_file(given)]
    if not others:
        return ""
    return (
        f"--weights {given}: the weights of {method_of_file(given)} alone, not of {', '.join(others)};"
        " give a folder that holds each method's <method>.pt, or run the others without this --weights"
    )


def weights_provenance(name: str, sensor: SensorConfig | None = None) -> dict[str, Any]:
    """The weights file ``name`` uses with ``sensor`` and its SHA-256, for the records of a run: results
    must say which weights produced them, since ``CSO_WEIGHTS_DIR`` (or ``CSO_WEIGHTS_FILE``) and the sensor can swap them."""
    path = weights_path(name, sensor)
    digest = file_sha256(path)
    given = given_weights_file()
    shipped = not os.environ.get(WEIGHTS_DIR_ENV) and path != given
    return {"path": str(path), "sha256": digest, "shipped": shipped}


def training_args(path: Path) -> dict[str, Any] | None:
    """The configuration (``ppo.Args`` as a mapping) the weights at ``path`` were trained with, from the record ``train``
    writes beside them (``<stem>.json``'s ``args``); None where no readable record says."""
    try:
        args = json.loads(path.with_suffix(".json").read_text())["args"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return args if isinstance(args, dict) else None


def training_sensor(path: Path) -> tuple[str, float] | None:
    """The sensor preset and field of view the weights at ``path`` were trained with, from the record ``train`` writes
    beside them (``<stem>.json``: ``args.sensor`` and ``args.lidar_fov_deg``); None where no readable record says."""
    args = training_args(path)
    try:
        preset = str(args.get("sensor", "lidar")) if args is not None else ""
        return None if args is None else (preset, SensorConfig.preset(preset, args.get("lidar_fov_deg")).fov_deg)
    except (ValueError, TypeError, ConfigError):
        return None


TRAINED_MASK_KEYS = {"stuck_avoid": "stuck_avoid", "mask_conflict": "conflict"}
"""``train``'s fields (``ppo.Args``) that set a key of the training episodes' ``masks``, by that key: ``eval`` and
``up`` run their own config's, and a policy does best with the masks it was trained under. The valid distance mask's
far bound (``beta_far_m``) is not among them: the recipe trains under the paper's 2 m and runs under 1.5 m on purpose
(``MaskConfig.beta_far_m``)."""


def trained_mask_settings(args: dict[str, Any]) -> dict[str, Any]:
    """The ``masks`` keys and values a training run's episodes ran with (``args``: its ``ppo.Args`` as a mapping, with
    its ``variant``), those of ``TRAINED_MASK_KEYS`` that its variant's masks use: the stuck mask's reference where it
    has the stuck mask, what wins a conflict where it has both. A field an older record lacks is not said."""
    from cso_runtime.policies import VARIANTS  # noqa: PLC0415 - no torch; policies imports this module

    variant = VARIANTS.get(str(args.get("variant")))
    if variant is None:
        return {}
    used = {"stuck_avoid": variant.use_stuck, "conflict": variant.use_stuck and variant.use_valid_distance}
    return {key: args[name] for name, key in TRAINED_MASK_KEYS.items() if name in args and used[key]}


def mask_settings_changed(trained: dict[str, Any], masks: MaskConfig) -> dict[str, Any]:
    """The ones of ``trained`` (``trained_mask_settings``) that ``masks`` runs otherwise, with the trained values."""
    return {key: value for key, value in trained.items() if getattr(masks, key) != value}


def mask_set_flags(changed: dict[str, Any], prefix: str = "") -> list[str]:
    """The ``--set`` words that run ``changed`` masks settings (``mask_settings_changed``); ``prefix``: where the
    command's keys hold the masks (``exploration.`` for ``up``, none for ``eval``)."""
    return [word for key, value in changed.items() for word in ("--set", f"{prefix}masks.{key}={value}")]


def mask_mismatches(names: list[str], masks: MaskConfig, sensor: SensorConfig | None = None, prefix: str = "") -> list[str]:
    """One line per method of ``names`` whose weights (for ``sensor``) were trained under other masks settings than
    ``masks``, as their record says, naming the ``--set`` that runs them as trained (``prefix``: as ``mask_set_flags``).
    Weights without a record, or a record from before these settings, are taken to match."""
    lines = []
    for name in names:
        path = weights_path(name, sensor)
        args = training_args(path)
        changed = mask_settings_changed(trained_mask_settings({**args, "variant": name}), masks) if args is not None else {}
        if changed:
            trained = ", ".join(f"masks.{k}={v}" for k, v in changed.items())
            ours = ", ".join(f"{getattr(masks, k)}" for k in changed)
            flags = " ".join(mask_set_flags(changed, prefix))
            lines.append(f"the weights of {name} were trained with {trained} ({path.with_suffix('.json')}), this run's are {ours}; {flags} runs them as trained")
    return lines


def sensor_mismatches(names: list[str], sensor: SensorConfig, eval_hint: bool = True) -> list[str]:
    """One line per field of view that some of ``names``' weights for ``sensor`` were trained with instead of
    ``sensor``'s, as their records say (``configs/train.yaml`` trains with the 360-degree LiDAR, ``eval`` runs the
    LIMO's 180-degree one unless told): a policy does best with the sensor it was trained with. Weights without a
    record are taken to match. ``eval_hint``: name the ``eval --lidar-fov`` (or ``--sensor``) that matches them (a
    robot's own sensor is what it is: ``up`` says no more)."""
    by_sensor: dict[tuple[str, float], list[str]] = {}
    for name in names:
        trained_sensor = training_sensor(weights_path(name, sensor))
        if trained_sensor is not None and trained_sensor[1] != sensor.fov_deg:
            by_sensor.setdefault(trained_sensor, []).append(name)
    lines = []
    for (preset, trained), which in by_sensor.items():
        record = weights_path(which[0], sensor).with_suffix(".json")
        lidar = trained in LIDAR_FOVS_DEG and sensor.fov_deg in LIDAR_FOVS_DEG  # a LiDAR eval: --lidar-fov is the fix
        flag = f"--lidar-fov {trained:g}" if preset == "lidar" and lidar else f"--sensor {preset}" if preset != "lidar" else ""
        hint = f"; eval {flag} runs {'it' if len(which) == 1 else 'them'} with that sensor" if eval_hint and flag else ""
        lines.append(
            f"the weights of {', '.join(which)} were trained with a {trained:g}-degree sensor ({record}{' and the like' if len(which) > 1 else ''}),"
            f" this run's sees {sensor.fov_deg:g} degrees{hint}"
        )
    return lines


TRAINED_FRONTIER_BEFORE_RECORD = FrontierConfig(min_cluster_size_m=0.3, entropy_window_m=2.0)
"""The frontier settings of a checkpoint written before checkpoints recorded theirs (``frontier``): every shipped
weights file, and every run of ``train`` until then. ``train`` has built its episodes' observations with
``FrontierConfig``'s defaults from its first commit until the record came (``ppo.Args.env_config``: ``ExplorationConfig()``;
no setting of ``Args`` nor of ``configs/train.yaml``, the recipe of BENCHMARKS.md's ``cso-runtime train --config
configs/train.yaml``, changed them then), and those defaults have been 0.3 m and 2 m since the first commit. Written out rather than read from
``FrontierConfig()``, so that a later default does not change what old weights are said to have been trained with. The
entropy window is in every checkpoint's ``graph`` too (``GraphConfig.entropy_window_m``, set by ``train`` to its
episodes' window, 2 m in each shipped file): ``trained_frontier`` reads it from there."""


INPUT_CHECKS: dict[str, bool] = {"entropy_window_m": True, "min_cluster_size_m": False}
"""The run settings (of ``frontier``) that change what the network is given, compared at every load with those the
weights were trained with (``checkpoint_frontier``: at every load, and before anything starts in ``up``); True: a mismatch
is refused (``registry.CheckpointError``; ``up``: a ConfigError), False: warned.

- ``entropy_window_m`` (gamma of Eq. 4), refused: the frontier service counts I over the run's window and the graph
  divides it by the trained one (``graph.build_graph``: I x cell size / window, about 1 along a straight frontier at the
  trained window), so another window scales the entropy input by about run / trained: a network fed inputs of another
  scale than it learned on, silently. Checked only for the variants that read I (``use_entropy``: not cso-no-info nor
  gnn-baseline, whose graphs hold 0 there). Weights for another window are trained with it (``train --set
  entropy_window_m=...``, ``ppo.Args.entropy_window_m``).
- ``min_cluster_size_m``, warned: it decides which frontier clusters become candidate goals, the network's actions (and
  the smallest ``size`` input a node may have), not what a node's inputs mean; every input keeps its scale, and a
  robot whose sensor leaves more or fewer short frontier fragments may need another value on purpose.

Not compared, each for its reason: the graph's own settings (``GraphConfig``: node limits, past-position nodes, knn,
distance scale, which features) come from the checkpoint itself, never from the run, so they cannot differ; the
sensor's field of view picks its own file (``weights.weights_path``: ``<method>@fov<deg>.pt``) and is warned of from
the record beside the weights (``weights.sensor_mismatches``), as the masks' stuck settings are
(``weights.mask_mismatches``): masks act on the network's output (the logits), not on its inputs, and the valid distance
mask's far bound is run other than trained on purpose; the map's cell size is each map's own, not a setting, and every
input is made free of it (lengths in metres over ``distance_scale_m``, I times the cell size), the recipe training at
0.05 and 0.1 m a cell; the robot's radius (which cells are traversable) and the replanning period (how far apart the
past-position nodes lie) are the robot's and the run's, and change what the inputs measure, never their scale."""


def trained_with_said(key: str, trained: float) -> str:
    """How ``InputMismatch.said`` names the setting of ``INPUT_CHECKS`` key ``key`` the weights were trained with: what
    tells its refusal from any other error of a run's settings (``doctor``: a profile refused for another window only)."""
    return f"were trained with frontier.{key} {setting_text(trained)} m"


@dataclasses.dataclass(frozen=True)
class InputMismatch:
    """One run setting of ``INPUT_CHECKS`` that differs from the weights' training."""

    key: str
    """The ``FrontierConfig`` field (``frontier.<key>`` in eval's ``--set``)."""
    trained: float
    run: float
    refused: bool

    def said(self, name: str, path: Path, against: str = "this run's") -> str:
        """One line naming the parameter, both values and how to proceed; ``against``: whose setting the weights' is
        compared with (``doctor``, which has no run: "the default config's")."""
        trained, run = setting_text(self.trained), setting_text(self.run)
        matching = f"--set frontier.{self.key}={trained} (up: --set exploration.frontier.{self.key}={trained})"
        head = f"the weights of {name} ({path}) {trained_with_said(self.key, self.trained)}, {against} is {run} m"
        if self.key == "entropy_window_m":
            return (
                f"{head}: the network's entropy input would be about {self.run / self.trained:g} times what it learned on;"
                f" run with {matching}, or with weights trained with a {run} m window"
                f" (cso-runtime train --config configs/train.yaml --set entropy_window_m={run})"
            )
        return f"{head}: its candidate goals would be other frontier clusters than it learned to choose among; {matching} runs them as trained"


def input_mismatches(trained: FrontierConfig, run: FrontierConfig, use_entropy: bool = True) -> list[InputMismatch]:
    """The settings of ``INPUT_CHECKS`` in which ``run`` differs from ``trained`` (``registry.trained_frontier``), in that order;
    the entropy window only where the variant reads I (``use_entropy``)."""
    found = []
    for key, refused in INPUT_CHECKS.items():
        if key == "entropy_window_m" and not use_entropy:
            continue
        was, now = float(getattr(trained, key)), float(getattr(run, key))
        if was != now:
            found.append(InputMismatch(key, was, now, refused))
    return found


@dataclasses.dataclass(frozen=True)
class InputVerdict:
    """What loading weights with a run's frontier settings refuses and what it warns of (``input_verdict``), one line
    each, in the words every loader says them with."""

    refused: tuple[str, ...] = ()
    warned: tuple[str, ...] = ()

    @property
    def refusal(self) -> str:
        """The refused lines as one message; "" where none is refused."""
        return "; ".join(self.refused)

    def __add__(self, other: InputVerdict) -> InputVerdict:
        """Both verdicts' lines, this one's first: what loading both sets of weights refuses and warns of."""
        return InputVerdict(self.refused + other.refused, self.warned + other.warned)


def input_verdict(
    name: str, path: Path, trained: FrontierConfig, run: FrontierConfig | None, graph_use_entropy: bool = True, against: str = "this run's"
) -> InputVerdict:
    """The one decision of what loading the weights of method ``name`` at ``path``, trained with the frontier settings
    ``trained`` (``checkpoint_frontier``), with the run's ``run`` (None: ``FrontierConfig``'s defaults, what
    ``ObservationBuilder()`` builds with) refuses and what it warns of (``input_mismatches``, ``INPUT_CHECKS``), with
    the messages (``InputMismatch.said``). The entropy window counts only for a variant that reads I
    (``policies.VARIANTS``; ``graph_use_entropy``, its graph's own switch, for a name that is no variant). Every load
    (``registry._model_for``), ``up``'s check and warnings before anything starts (``recorded_input_verdict``) and
    benchmarks/eval_ensemble.py's members decide with it; ``doctor`` too, with ``against`` naming the settings it compares
    with (``InputMismatch.said``)."""
    from cso_runtime.policies import VARIANTS  # noqa: PLC0415 - no torch; policies imports this module

    use_entropy = VARIANTS[name].use_entropy if name in VARIANTS else graph_use_entropy
    mismatches = input_mismatches(trained, run or FrontierConfig(), use_entropy)
    return InputVerdict(
        refused=tuple(m.said(name, path, against) for m in mismatches if m.refused),
        warned=tuple(m.said(name, path, against) for m in mismatches if not m.refused),
    )


def checkpoint_frontier(ckpt: Mapping[str, Any], graph_window_m: float) -> FrontierConfig:
    """The frontier settings the weights of ``ckpt`` (a checkpoint ``registry.save_checkpoint`` wrote, whose graph
    divides I by ``graph_window_m``) were trained with: its ``frontier`` record, or, in a checkpoint written before the
    record, ``TRAINED_FRONTIER_BEFORE_RECORD`` with the entropy window of its graph. A key the record lacks (a later
    setting) takes the value of before the record. Every load (``registry.trained_frontier``) and ``up``'s check before
    anything starts (``recorded_frontier``) read it so."""
    before = dataclasses.replace(TRAINED_FRONTIER_BEFORE_RECORD, entropy_window_m=float(graph_window_m))
    record = ckpt.get("frontier")
    if not isinstance(record, dict):
        return before
    known = {f.name for f in dataclasses.fields(FrontierConfig)}
    return dataclasses.replace(before, **{k: value for k, v in record.items() if k in known and (value := _finite(v)) is not None})


def _finite(value: Any) -> float | None:
    """``value`` as a finite float where it is a number (not a bool, not a text) that is one; None otherwise (an int
    too large for a float, NaN, infinity: not a setting ``train`` wrote). ``config.finite_number``, less its reading
    of texts: a record holds numbers."""
    return None if isinstance(value, str) else finite_number(value)


CHECKPOINT_HEADER_MAX_BYTES = 256 * 1024
"""The largest pickle of a checkpoint's plain data (``data.pkl``: its tensors are kept apart) that ``checkpoint_header``
reads: a cso-runtime checkpoint's is about 4 kB (a few dozen tensors' entries and the settings). What a pickle builds
grows with its size (some 70 bytes of objects per byte; a dict of keys of one hash takes time growing with their
square): a crafted file of this size costs at most tens of MB and a few seconds (20,000 int keys of one hash: 2 s)."""


def _no_tensor(*_args: Any, **_kwargs: Any) -> None:
    """What a tensor (and its storage) of a checkpoint stands as when ``checkpoint_header`` reads it: nothing."""


class _HeaderUnpickler(pickle._Unpickler):
    """``torch.save``'s ``data.pkl`` read without torch: tensors and their storages (persistent ids, torch's rebuild
    functions) stand as None, and no other class than an ``OrderedDict`` is built, so that reading a file runs none of
    its code (``torch.load(weights_only=True)`` allows no more). Python's own unpickler, not the C one: that one grows its
    memo to the largest index a pickle names (a 9-byte pickle naming index 2**32 - 1 asks for 64 GiB, and zeroes it),
    where Python's keeps a dict, as torch's weights-only unpickler does."""

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) == ("collections", "OrderedDict"):
            return collections.OrderedDict
        if (module == "torch._utils" and name.startswith("_rebuild_")) or (module == "torch" and name.endswith("Storage")):
            return _no_tensor
        raise pickle.UnpicklingError(f"{module}.{name}: not read without torch")

    def persistent_load(self, pid: Any) -> None:
        return None


def checkpoint_header(path: Path) -> dict[str, Any] | None:
    """The plain data of the checkpoint at ``path`` (``registry.save_checkpoint``'s ``variant``, ``network``, ``graph``,
    ``frontier``, ``extra``; its ``state_dict``'s tensors as None), read from ``torch.save``'s zip archive without
    torch; None for a file that is not one (missing, another program's, torch's legacy pickle: the load says more).
    Only a ``data.pkl`` stored as ``torch.save`` stores it (uncompressed, at most ``CHECKPOINT_HEADER_MAX_BYTES``) is
    read: ``zipfile`` inflates a compressed entry whole before it cuts it to the size the archive says (a few hundred
    bytes of bzip2 make gigabytes)."""
    try:
        with zipfile.ZipFile(path) as archive:
            pickles = [info for info in archive.infolist() if info.filename.endswith("/data.pkl") and info.filename.count("/") == 1]
            if len(pickles) != 1:
                return None
            info = pickles[0]
            if info.compress_type != zipfile.ZIP_STORED or info.compress_size != info.file_size or info.file_size > CHECKPOINT_HEADER_MAX_BYTES:
                return None
            data = archive.read(info)
        header = _HeaderUnpickler(io.BytesIO(data)).load()
    except Exception:  # noqa: BLE001 - a zip or a pickle of anything else: not said here, the load says what it is
        return None
    return header if isinstance(header, dict) else None


def recorded_frontier(path: Path) -> FrontierConfig | None:
    """The frontier settings the weights at ``path`` were trained with, as the checkpoint itself records them
    (``checkpoint_frontier`` of its ``checkpoint_header``), without torch: the very record every load compares
    (``registry.trained_frontier``), not the ``.json`` beside it, which a file copied over the weights leaves telling of
    other weights. None where the file does not read so (the load says why)."""
    header = checkpoint_header(path)
    graph = header.get("graph") if header is not None else None
    if header is None or not isinstance(graph, dict):
        return None
    window = graph.get("entropy_window_m", TRAINED_FRONTIER_BEFORE_RECORD.entropy_window_m)  # GraphConfig's default, the same 2 m
    if (graph_window := _finite(window)) is None or graph_window <= 0:
        return None  # not a graph save_checkpoint wrote: the load says what it is
    return checkpoint_frontier(header, graph_window)


def recorded_input_verdict(name: str, frontier: FrontierConfig, sensor: SensorConfig | None = None) -> InputVerdict:
    """What loading ``name``'s weights (for ``sensor``) with the run's ``frontier`` settings would refuse and warn of
    (``input_verdict``, the very decision of the policy service's load, ``registry._model_for``), as the checkpoint
    records them (``recorded_frontier``), in the policy service's words: what ``up`` refuses (``recorded_input_refusal``)
    and says on its terminal (``cli._warn_of_weights_trained_otherwise``) before it starts anything, where the policy
    service would refuse it, or warn of it in its own log only, at its start. Nothing where they match or the file does
    not read without torch (the policy service's load then says it)."""
    from cso_runtime.policies import VARIANTS  # noqa: PLC0415 - no torch; policies imports this module

    path = weights_path(name, sensor)
    trained = recorded_frontier(path)
    if trained is None or name not in VARIANTS:
        return InputVerdict()
    return input_verdict(name, path, trained, frontier)


def recorded_input_refusal(name: str, frontier: FrontierConfig, sensor: SensorConfig | None = None) -> str:
    """What loading ``name``'s weights (for ``sensor``) with the run's ``frontier`` settings would refuse
    (``recorded_input_verdict``'s refusal): what ``up`` refuses before it starts anything, where the policy service
    would refuse it at its start. "" where they match or the file does not read without torch."""
    return recorded_input_verdict(name, frontier, sensor).refusal
