"""``python -m patchcloud.stream.cli``: the ``patchcloud`` command."""

from patchcloud.stream.cli import run

if __name__ == "__main__":
    run()
