"""``python -m synth``: the command line of :mod:`synth.commands`."""

from synth.commands import console_main, main

__all__ = ["console_main", "main"]

if __name__ == "__main__":
    console_main()
