"""Errors that the CLI turns into one clear line and exit code 2."""


class TvfError(Exception):
    """Base class for every error caused by bad input (names, files, arguments, actions)."""
