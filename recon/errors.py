"""Typed exceptions shared by the Python API and the command line.

The CLI turns an :class:`InputError` into one line on stderr and exit status 2; anything else is a
bug and keeps its traceback.
"""


class InputError(ValueError):
    """Bad input from a user: a file, a shape, a value or a parameter that cannot be used."""
