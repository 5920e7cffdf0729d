"""The studies' subcommands (``python -m lab COMMAND``), each with ``register(subparsers)``."""
