"""cso-runtime: active scene mapping with CSO (ACM MM 2024) on a LIMO robot."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("cso-runtime")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"
