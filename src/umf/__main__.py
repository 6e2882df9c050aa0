"""``python -m umf``: the same command as ``umf``."""

from umf.cli.main import run

if __name__ == "__main__":
    run()
