"""The runtime's services, one OS process each: ``python -m services.<name>`` or
``cso-runtime service NAME``. Each is a thin shell around core objects (see services/common.py).

A profile may also run a service of one's own, a ``Service`` subclass named ``module.path:Attribute`` in its
section's ``class`` key, beside the built-in ones or in place of one of them, or any executable named in its
``command`` key (a node in any language: docs/own-service.md)."""

from __future__ import annotations

import importlib
import os
import re
import shlex
import shutil
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from services.common import Service

SERVICE_NAMES = ("sim", "mapper", "frontier", "policy", "planner", "ros2_bridge", "foxglove_bridge")
"""The services a profile may list (``ros2_bridge`` replaces ``sim`` on a real robot; ``foxglove_bridge``, a
viewer's live feed, only listens)."""

_CLASSES: dict[str, tuple[str, str | None]] = {
    "sim": ("SimService", "SimParams"),
    "mapper": ("MapperService", "MapperParams"),
    "frontier": ("FrontierService", "FrontierParams"),
    "policy": ("PolicyService", "PolicyParams"),
    "planner": ("PlannerService", "PlannerParams"),
    "ros2_bridge": ("Ros2BridgeService", "Ros2BridgeParams"),
    "foxglove_bridge": ("FoxgloveBridgeService", "FoxgloveBridgeParams"),
}
"""Service name -> (its Service subclass, its parameter dataclass or None when it takes none), both in
``services.<name>``."""

OWN_CLASS_KEY = "class"
"""The key of a profile's service section (``services.<name>.class``) that names a service of one's own,
``module.path:Attribute``: ``up`` starts that class under ``<name>`` instead of a built-in one."""

COMMAND_KEY = "command"
"""The key of a profile's service section (``services.<name>.command``) that names an executable of one's own, a list
of arguments or one string split as a shell would (``shlex``): ``up`` starts it under ``<name>`` (a command node)."""

COMMAND_NODE_KEYS = {
    COMMAND_KEY: "the executable and its arguments",
    "inputs": "the topics it subscribes to (the runtime's, or its own: ext/<name>), for `dataflow` and up's checks",
    "outputs": "the topics it publishes (the runtime's, or its own: ext/<name>), for `dataflow` and up's checks",
    "alive_token": "true: it declares the liveliness token $CSO_ALIVE_KEY once ready, and step 0 waits for it",
}
"""What a command node's section may hold: the launcher cannot ask an executable what it reads and writes, so the
profile says it (docs/own-service.md, A node in any language)."""

NOT_REPLACEABLE = ("sim", "ros2_bridge", "foxglove_bridge")
"""Built-in services a class of one's own cannot stand in for: the referees own the episode (the launcher and the
other services read their parameters), and the launcher reads the Foxglove bridge's to say where to connect."""

_SERVICE_NAME = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
RESERVED_NAMES = ("launcher",)
"""Names no service may take: the launcher's own (its log, its node in the dataflow)."""

OWN_SERVICE_SPELLING = "a service of your own is written module.path:Attribute, a Service subclass (e.g. my_nodes:CoverageLogger)"


def _lookup(name: str, index: int) -> Any:
    if name not in _CLASSES:
        from cso_runtime.config import with_nearest  # noqa: PLC0415

        said = with_nearest(name, SERVICE_NAMES, shown=repr(name))
        raise ValueError(f"unknown service {said}; choose one of {', '.join(SERVICE_NAMES)}, or a service of your own as module.path:Attribute")
    attr = _CLASSES[name][index]
    return None if attr is None else getattr(importlib.import_module(f"services.{name}"), attr)


def service_class(name: str) -> type[Service]:
    """The Service subclass of ``name`` (imported lazily: each pulls in its own dependencies)."""
    cls = _lookup(name, 0)
    assert cls is not None
    return cls


def params_class(name: str) -> type | None:
    """The parameter dataclass of service ``name`` (``services.<name>`` in a profile), or None."""
    return _lookup(name, 1)


def own_class_spec(section: Any) -> str | None:
    """The ``module.path:Attribute`` a profile's service section names under ``class`` (a service of one's own), or
    None: the built-in service of its name."""
    if isinstance(section, dict) and section.get(OWN_CLASS_KEY) is not None:
        return str(section[OWN_CLASS_KEY])
    return None


def command_argv(section: Any) -> list[str] | None:
    """The argv a profile's service section names under ``command`` (a node in any language), or None: unchecked
    (``check_command_node`` checks it)."""
    if not isinstance(section, dict) or section.get(COMMAND_KEY) is None:
        return None
    command = section[COMMAND_KEY]
    return shlex.split(command) if isinstance(command, str) else [str(arg) for arg in command]


def is_own_node(section: Any) -> bool:
    """Whether a profile's service section runs something of the user's own (``class`` or ``command``); a command that
    cannot be split (an unclosed quote) is one too, for ``check_command_node`` to refuse with its reason."""
    return own_class_spec(section) is not None or (isinstance(section, dict) and section.get(COMMAND_KEY) is not None)


def waited_for_at_start(section: Any) -> bool:
    """Whether the sim's step 0 waits for the liveliness token of the service a profile's section runs: every one
    but a command node that does not declare one (``alive_token``), which could never be seen to come up."""
    return command_argv(section) is None or section.get("alive_token") is True


def command_topics(section: Any, kind: str) -> tuple[str, ...]:
    """The topics a command node's section declares under ``kind`` (``inputs`` or ``outputs``)."""
    return tuple((section or {}).get(kind) or ())


def check_command_node(name: str, section: dict[str, Any]) -> list[str]:
    """The argv of the command node a profile's ``services.<name>`` section names, checked: a ConfigError for a
    command that is no list of strings nor a string, an executable not found or not executable (a relative path:
    from the folder ``up`` runs from, as the node runs there; a bare name: on ``PATH``), a ``class`` beside it, a key
    it does not take, topics neither the runtime's nor of one's own (``ext/<name>``), an ``alive_token`` that is no
    boolean."""
    from cso_runtime.config import ConfigError  # noqa: PLC0415
    from cso_runtime.keys import TOPICS, is_ext_topic  # noqa: PLC0415

    where = f"services.{name}"
    if own_class_spec(section) is not None:
        raise ConfigError(f"{where}: both {OWN_CLASS_KEY} and {COMMAND_KEY}; a service is a Python class of your own or an executable, not both")
    if name in NOT_REPLACEABLE:
        raise ConfigError(f"{where}.{COMMAND_KEY}: the built-in {name} cannot be replaced by a node of your own (it owns the episode, or the launcher reads its parameters)")
    check_service_name(name, where)
    unknown = [key for key in section if key not in COMMAND_NODE_KEYS]
    if unknown:
        said = "; ".join(f"{key}: {why}" for key, why in COMMAND_NODE_KEYS.items())
        raise ConfigError(f"{where}: a command node takes no {', '.join(map(repr, unknown))} (its keys: {said})")
    command = section[COMMAND_KEY]
    if isinstance(command, str):
        try:
            argv = shlex.split(command)
        except ValueError as exc:
            raise ConfigError(f"{where}.{COMMAND_KEY}: cannot split {command!r} as a shell would: {exc}") from None
    elif isinstance(command, list) and all(isinstance(arg, str | int | float) and not isinstance(arg, bool) for arg in command):
        argv = [str(arg) for arg in command]
    else:
        raise ConfigError(f"{where}.{COMMAND_KEY}: expected a list of arguments or one string, got {command!r}")
    if not argv or not argv[0]:
        raise ConfigError(f"{where}.{COMMAND_KEY}: empty; give the executable and its arguments, e.g. [./my_node, --rate, '10']")
    exe = argv[0]
    if os.sep in exe:
        if not os.path.isfile(exe):
            raise ConfigError(f"{where}.{COMMAND_KEY}: executable {exe!r} not found (a relative path is from the folder `up` runs from, {os.getcwd()})")
        if not os.access(exe, os.X_OK):
            raise ConfigError(f"{where}.{COMMAND_KEY}: {exe!r} is not executable (chmod +x it, or start it with its interpreter: [python3, {exe}])")
    elif shutil.which(exe) is None:
        raise ConfigError(f"{where}.{COMMAND_KEY}: executable {exe!r} not found on PATH (give a path, ./{exe}, for one in this folder)")
    for kind in ("inputs", "outputs"):
        topics = section.get(kind) or []
        if not isinstance(topics, list) or not all(isinstance(t, str) for t in topics):
            raise ConfigError(f"{where}.{kind}: expected a list of topic names, got {topics!r}")
        for topic in topics:
            if topic not in TOPICS and not is_ext_topic(topic):
                raise ConfigError(
                    f"{where}.{kind}: {topic!r} is none of the runtime's topics ({', '.join(TOPICS)}) nor one of your own, ext/<name> (docs/own-service.md)"
                )
    if not isinstance(section.get("alive_token", False), bool):
        raise ConfigError(f"{where}.alive_token: expected true or false, got {section['alive_token']!r}")
    return argv


def service_params(section: Any) -> dict[str, Any]:
    """A profile's service section as the service gets its parameters: without the ``class`` that picks it."""
    return {k: v for k, v in (section or {}).items() if k != OWN_CLASS_KEY}


def check_service_name(name: str, where: str) -> str:
    """``name`` when a service may have it (it stands in keys ``cso/<robot>/alive/<name>`` and names its log); a
    ConfigError otherwise."""
    from cso_runtime.config import ConfigError  # noqa: PLC0415

    if not isinstance(name, str) or not _SERVICE_NAME.match(name) or name in RESERVED_NAMES:
        raise ConfigError(f"{where}: a service's name must be 1-64 letters, digits, '_' or '-', and not {', '.join(RESERVED_NAMES)}; got {name!r}")
    return name


def own_service_class(spec: str, name: str | None = None) -> type[Service]:
    """The Service subclass ``spec`` (``module.path:Attribute``) names, checked: a ``name`` fit for keys (``name`` given:
    that one, the profile's key it is listed under), inputs and outputs on known topics with message types. A
    ConfigError says what is wrong, so that ``up`` refuses it before anything starts."""
    from cso_runtime.config import ConfigError, import_attribute  # noqa: PLC0415
    from cso_runtime.keys import TOPICS, is_ext_topic  # noqa: PLC0415
    from cso_runtime.messages import Message  # noqa: PLC0415
    from services.common import Service  # noqa: PLC0415 - imports zenoh

    where = f"services.{name}.{OWN_CLASS_KEY}" if name else "service"
    cls = import_attribute(spec, f"{where} {spec!r}", OWN_SERVICE_SPELLING)
    if not (isinstance(cls, type) and issubclass(cls, Service)):
        raise ConfigError(f"{where} {spec!r}: a {type(cls).__name__}, not a subclass of services.common.Service")
    check_service_name(cls.name, f"{where} {spec!r}: its name")
    if name is not None and cls.name != name:
        instead = f"to stand in for the built-in {name}, " if name in SERVICE_NAMES else ""
        raise ConfigError(
            f"{where} {spec!r}: the class is named {cls.name!r} (its `name`), and a profile lists a service under its name: "
            f"{instead}set its name to {name!r}, or list it as services.{cls.name}"
        )
    for kind in ("inputs", "outputs"):
        ports = getattr(cls, kind)
        if not isinstance(ports, dict):
            raise ConfigError(f"{where} {spec!r}: {kind} must be a mapping of topic -> message type")
        for topic, msg_type in ports.items():
            if is_ext_topic(topic):  # a topic of one's own: raw bytes, no schema of the runtime's
                if msg_type is not bytes:
                    raise ConfigError(f"{where} {spec!r}: {kind}[{topic!r}] is a topic of your own, which carries bytes: declare it as `bytes`, got {msg_type!r}")
                continue
            if topic not in TOPICS:
                by_key = {key: name for name, key in TOPICS.items()}
                hint = f": key {topic} is topic {by_key[topic]!r}" if topic in by_key else ""
                raise ConfigError(
                    f"{where} {spec!r}: {kind} names topic {topic!r}, which is none of the runtime's topics{hint} "
                    f"({', '.join(TOPICS)}; a topic of your own is ext/<name>, of bytes: docs/own-service.md)"
                )
            if not (isinstance(msg_type, type) and issubclass(msg_type, Message)):
                raise ConfigError(f"{where} {spec!r}: {kind}[{topic!r}] must be a message class of cso_runtime.messages, got {msg_type!r}")
    return cls


def profile_service_class(name: str, section: Any = None) -> type[Service]:
    """The Service subclass a profile runs as ``name``: the class its section names (``class``), else the built-in one."""
    spec = own_class_spec(section)
    if spec is None:
        return service_class(name)
    return own_service_class(spec, name)


def check_profile_service(name: str, section: Any) -> None:
    """A ConfigError unless a profile's ``services.<name>`` section can run: a built-in service with its parameters,
    or a class of one's own (``class``, not in place of ``NOT_REPLACEABLE``) with the parameters its ``params_class``
    takes (any mapping without one)."""
    from cso_runtime.config import ConfigError, from_dict, with_nearest  # noqa: PLC0415

    if section is not None and not isinstance(section, dict):
        raise ConfigError(f"services.{name}: expected a mapping of parameters")
    if isinstance(section, dict) and section.get(COMMAND_KEY) is not None:
        check_command_node(name, section)
        return
    spec = own_class_spec(section)
    if spec is None:
        if name not in SERVICE_NAMES:
            raise ConfigError(
                f"services: unknown service {with_nearest(name, SERVICE_NAMES, shown=repr(name))}; known: {', '.join(SERVICE_NAMES)}; a service of your own names its class: "
                f"`{name}: {{{OWN_CLASS_KEY}: module.path:Attribute}}`, or an executable: `{name}: {{{COMMAND_KEY}: [./my_node]}}` (docs/own-service.md)"
            )
        params_cls = params_class(name)
        if params_cls is not None:
            from_dict(params_cls, section or {}, where=f"services.{name}")
        elif section:
            raise ConfigError(f"services.{name}: takes no parameters, got {', '.join(section)}")
        return
    if name in NOT_REPLACEABLE:
        raise ConfigError(f"services.{name}.{OWN_CLASS_KEY}: the built-in {name} cannot be replaced by a class of your own (it owns the episode, or the launcher reads its parameters)")
    check_service_name(name, f"services.{name}")
    cls = own_service_class(spec, name)
    if cls.params_class is not None:
        from_dict(cls.params_class, service_params(section), where=f"services.{name}")


def command_service_class(name_or_spec: str) -> type[Service]:
    """The class ``cso-runtime service NAME`` (or ``python -m services NAME``) runs: a built-in service by its name, or a
    service of one's own as ``module.path:Attribute``; ValueError (ConfigError) saying why not."""
    if ":" in name_or_spec:
        return own_service_class(name_or_spec)
    return service_class(name_or_spec)
