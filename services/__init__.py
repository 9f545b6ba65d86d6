"""The runtime's services, one OS process each: ``python -m services.<name>`` or
``cso-runtime service NAME``. Each is a thin shell around core objects (see services/common.py)."""

from __future__ import annotations

import importlib

SERVICE_NAMES = ("sim", "mapper", "frontier", "policy", "planner")
"""The five services of a profile."""

_CLASSES = {"sim": "SimService", "mapper": "MapperService", "frontier": "FrontierService", "policy": "PolicyService", "planner": "PlannerService"}


def service_class(name: str) -> type:
    """The Service subclass of ``name`` (imported lazily: each pulls in its own dependencies)."""
    if name not in _CLASSES:
        raise ValueError(f"unknown service {name!r}; choose one of {', '.join(SERVICE_NAMES)}")
    return getattr(importlib.import_module(f"services.{name}"), _CLASSES[name])
