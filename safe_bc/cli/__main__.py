"""``python -m safe_bc.cli``: the ``safe-bc`` command (its exit status too)."""

from safe_bc.cli.commands import main

if __name__ == "__main__":
    raise SystemExit(main())
