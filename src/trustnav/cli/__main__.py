"""``python -m trustnav.cli``: the ``trustnav`` command."""

from trustnav.cli import main

if __name__ == "__main__":
    raise SystemExit(main())
