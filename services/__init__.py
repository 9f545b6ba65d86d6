"""The runtime's services, one OS process each: ``python -m services.<name>`` or
``cso-runtime service NAME``. Each is a thin shell around core objects (see services/common.py)."""

from __future__ import annotations

import importlib

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


def _lookup(name: str, index: int) -> type | None:
    if name not in _CLASSES:
        raise ValueError(f"unknown service {name!r}; choose one of {', '.join(SERVICE_NAMES)}")
    attr = _CLASSES[name][index]
    return None if attr is None else getattr(importlib.import_module(f"services.{name}"), attr)


def service_class(name: str) -> type:
    """The Service subclass of ``name`` (imported lazily: each pulls in its own dependencies)."""
    cls = _lookup(name, 0)
    assert cls is not None
    return cls


def params_class(name: str) -> type | None:
    """The parameter dataclass of service ``name`` (``services.<name>`` in a profile), or None."""
    return _lookup(name, 1)
