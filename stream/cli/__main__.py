"""``python -m patchcloud.stream.cli``: the ``patchcloud`` command."""

from patchcloud.stream.cli import main

if __name__ == "__main__":
    main()
