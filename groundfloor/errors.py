"""The one exception type for bad input, shared by all three packages.

The command line turns an :class:`InputError` into a one-line message and exit code 2; anything
else is a bug and shows a traceback (with ``--verbose``) or a one-line internal error.
"""


class InputError(ValueError):
    """Bad input: the message names the file, run, topic or key at fault, in one line."""
