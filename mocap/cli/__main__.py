"""``python -m mocap.cli``: the ``mocap`` command."""

from mocap.cli.app import main

if __name__ == "__main__":
    main()
