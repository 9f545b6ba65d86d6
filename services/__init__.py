"""The runtime's services, one OS process each: ``python -m services.<name>`` or
``cso-runtime service NAME``. Each is a thin shell around core objects (see services/common.py).

A profile may also run a service of one's own, a ``Service`` subclass named ``module.path:Attribute`` in its
section's ``class`` key, beside the built-in ones or in place of one of them (docs/own-service.md)."""

from __future__ import annotations

import importlib
import re
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

NOT_REPLACEABLE = ("sim", "ros2_bridge", "foxglove_bridge")
"""Built-in services a class of one's own cannot stand in for: the referees own the episode (the launcher and the
other services read their parameters), and the launcher reads the Foxglove bridge's to say where to connect."""

_SERVICE_NAME = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
RESERVED_NAMES = ("launcher",)
"""Names no service may take: the launcher's own (its log, its node in the dataflow)."""

OWN_SERVICE_SPELLING = "a service of your own is written module.path:Attribute, a Service subclass (e.g. my_nodes:CoverageLogger)"


def _lookup(name: str, index: int) -> Any:
    if name not in _CLASSES:
        raise ValueError(f"unknown service {name!r}; choose one of {', '.join(SERVICE_NAMES)}, or a service of your own as module.path:Attribute")
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
    from cso_runtime.keys import TOPICS  # noqa: PLC0415
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
            if topic not in TOPICS:
                by_key = {key: name for name, key in TOPICS.items()}
                hint = f": key {topic} is topic {by_key[topic]!r}" if topic in by_key else ""
                raise ConfigError(
                    f"{where} {spec!r}: {kind} names topic {topic!r}, which is none of the runtime's topics{hint} "
                    f"({', '.join(TOPICS)}; docs/own-service.md)"
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
    from cso_runtime.config import ConfigError, from_dict  # noqa: PLC0415

    if section is not None and not isinstance(section, dict):
        raise ConfigError(f"services.{name}: expected a mapping of parameters")
    spec = own_class_spec(section)
    if spec is None:
        if name not in SERVICE_NAMES:
            raise ConfigError(
                f"services: unknown service {name!r}; known: {', '.join(SERVICE_NAMES)}; a service of your own names its class: "
                f"`{name}: {{{OWN_CLASS_KEY}: module.path:Attribute}}` (docs/own-service.md)"
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
