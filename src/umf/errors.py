"""The one exception type the CLI turns into a one-line message and a non-zero exit."""


class UMFError(Exception):
    """A user-facing error: bad input, missing file, corrupt data. Message is one line."""
