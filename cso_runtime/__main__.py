"""``python -m cso_runtime``: the ``cso-runtime`` command (``python -m cso_runtime eval ...``), for an environment
whose scripts folder is not on PATH; it said "No module named cso_runtime.__main__"."""

from cso_runtime import main

if __name__ == "__main__":
    main()
