"""The one exception type for bad input, shared by all three packages.

The command line turns an :class:`InputError` into a one-line message and exit code 2; anything
else is a bug and shows a traceback (with ``--verbose``) or a one-line internal error.
"""


class InputError(ValueError):
    """Bad input: the message names the file, run, topic or key at fault, in one line."""


class DivergenceError(InputError):
    """A filter's state or covariance became non-finite: the message names the run and the time.

    ``t_s`` (seconds since the run's start) lets a caller keep what came before and let the other
    estimators finish (the benchmark does).
    """

    def __init__(self, message: str, t_s: float = float("nan")):
        super().__init__(message)
        self.t_s = float(t_s)
