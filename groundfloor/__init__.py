"""The ground floor: what every package of sindy-ekf stands on, importing nothing of the project.

- :mod:`groundfloor.errors`: :class:`~groundfloor.errors.InputError`, the one bad-input exception;
- :mod:`groundfloor.files`: atomic writers and output-path checks (never half a result);
- :mod:`groundfloor.progress`: progress bars, silent unless the command line switches them on;
- :mod:`groundfloor.angles`: angle wrapping, written once;
- :mod:`groundfloor.types`: the stage values that flow between preprocessing and identification;
- :mod:`groundfloor.gnss`: the GNSS measurement type the filters consume, and its checks;
- :mod:`groundfloor.dynamics`: the one dynamics interface and the eq. 5.75 kinematics;
- :mod:`groundfloor.results`: result values shared by stages (the 5 s prediction error).

``simulation``, ``identification`` and ``sindy_ekf`` import from here; this package imports
none of them (``tests/test_architecture.py`` checks it).
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("sindy-ekf")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0.0.0+unknown"
