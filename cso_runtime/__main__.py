"""``python -m cso_runtime``: the ``cso-runtime`` command, through the package's ``main`` as the installed script runs
it (a Ctrl-C while the CLI loads included). ``python -m cso_runtime`` said "No module named cso_runtime.__main__"."""

from cso_runtime import main

if __name__ == "__main__":
    main()
