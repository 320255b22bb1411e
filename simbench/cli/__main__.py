"""``python -m simbench.cli``: the ``simbench`` command."""

from simbench.cli.app import main

if __name__ == "__main__":
    main()
