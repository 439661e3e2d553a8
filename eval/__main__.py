"""``python -m eval <command> …`` — see :mod:`eval.cli`."""

from eval.cli import console_main, main

__all__ = ["console_main", "main"]

if __name__ == "__main__":
    console_main()
