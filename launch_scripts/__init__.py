"""Entry points that start the toolkit's processes (``python -m launch_scripts.<name>``), and
the orchestration of the trials: command lines and processes only, the logic they run lives
in the packages below (docs/architecture.md)."""
