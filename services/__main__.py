"""``python -m services NAME [options]``: one service, built in (``mapper``) or of one's own (``module.path:Attribute``,
a ``Service`` subclass), as ``cso-runtime service NAME`` runs it; what ``up`` starts for a profile's
``services.<name>.class`` (docs/own-service.md)."""

from __future__ import annotations

import logging
import sys

from cso_runtime.config import EXIT_BAD_CONFIG, LOG_FORMAT, ConfigError
from services import command_service_class
from services.common import service_main


def main(argv: list[str] | None = None) -> int:
    """Run the service named by the first argument with the rest; exit code 2 for an unknown one or a bad config."""
    args = sys.argv[1:] if argv is None else argv
    if not args or args[0].startswith("-"):
        print("usage: python -m services NAME|module.path:Attribute [--config FILE | --attach] [options]", file=sys.stderr)
        return EXIT_BAD_CONFIG
    try:
        cls = command_service_class(args[0])
    except (ConfigError, ValueError) as exc:
        logging.basicConfig(level=logging.INFO, format=LOG_FORMAT, stream=sys.stderr)
        logging.getLogger("cso.service").error("%s: bad configuration: %s", args[0], exc)
        return EXIT_BAD_CONFIG
    return service_main(cls, args[1:], prog=f"python -m services {args[0]}")


if __name__ == "__main__":
    raise SystemExit(main())
