"""sindy-ekf: identified SINDy driving dynamics of a skid-steered robot as the process model of
an EKF and a factor graph, benchmarked against laser-tracker truth.

The project is split as the data flow is (``docs/ARCHITECTURE.md``):

- :mod:`groundfloor`: errors, files, progress, angles, stage values, the GNSS measurement type,
  the dynamics interface; imports nothing of the project;
- :mod:`simulation`: a faithful simulator of the robot and of the laser-tracker campaign
  (writes the data contract), and the degraded-GNSS generator;
- :mod:`identification`: :mod:`identification.preprocessing` (raw bags to poses and body-frame
  states, thesis 5.1, 5.2) and :mod:`identification.sindy` (integral SINDy with control, 5.3);
- :mod:`sindy_ekf`: estimation (process models, EKF, factor graph), benchmark, diagnosis,
  report and the ``sindy-ekf`` command line.
"""

from groundfloor import __version__

__all__ = ["__version__"]
