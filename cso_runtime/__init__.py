"""cso-runtime: active scene mapping with CSO (ACM MM 2024) on a LIMO robot."""


def __getattr__(name: str) -> str:
    """``__version__``, looked up when first asked for: ``importlib.metadata`` (and the email, calendar and re modules
    it imports) is not loaded by every ``import cso_runtime``, which each command, service and launcher does first,
    before any of its own code could handle a Ctrl-C (the traceback of a Ctrl-C in a command's first moments)."""
    if name != "__version__":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version  # noqa: PLC0415

    try:
        value = version("cso-runtime")
    except PackageNotFoundError:  # a source tree that was never installed
        value = "0+unknown"
    globals()["__version__"] = value
    return value
